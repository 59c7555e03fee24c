"""The assembly of one episode: its config, the in-process and process runners, the console."""
