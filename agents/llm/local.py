"""A local GGUF model served in-process by llama.cpp's own HTTP server (the `xllamacpp` wheel).

`--llm gguf:PATH` needs no model server of its own: `LocalModelServer` loads the file when the
episode starts, serves the OpenAI-compatible API on an ephemeral loopback port, and frees it when
the episode ends. It has one slot (parallel sequence) per robot, so the robots' requests are
decoded together in llama.cpp's continuous batch instead of queueing behind each other.

What xllamacpp (2026.10) does that this module works around, all measured:

* `xllamacpp.Server(params)` holds the GIL for the whole load (its Cython constructor has no
  `nogil` block), so `asyncio.to_thread` keeps the load off the event loop's thread but NOT out of
  its way: every Python thread, the loop included, stalls for the load (about 1 s for Gemma 3
  270M). Reading the file once beforehand (which does release the GIL) moves the disk time out
  of that stall; the rest is unavoidable in-process.
* Its destructor stops the server by joining llama.cpp's main-loop thread, again holding the
  GIL. Two ways that join never returns, freezing the whole process: (1) the server is dropped
  before its loop has started (the stop signal is lost; about one in six immediate
  start-then-stop cycles hung), so `start()` waits for one request to pass through the loop
  before returning; (2) a request is still in flight (the loop is gone, so its HTTP handler
  waits for a result that never comes, or for its client to hang up, which an in-process client
  cannot do without the GIL), so `stop()` first waits for every slot to be idle. llama.cpp does
  not cancel a non-streaming request whose client hung up (it decodes on to max_tokens), so
  stop() may wait out the longest reply in flight; a streamed one (mhrc's default) ends as soon
  as its client closes the stream.
* llama.cpp logs every request to stderr by default (verbosity 3 = info): `verbosity=1` keeps
  errors only (0 drops them too); the threshold is process-wide.
* A GGUF without an embedded chat template (the packaged Gemma 3 270M has none) is silently
  formatted as ChatML, which Gemma does not know; for Gemma the known Gemma template is passed.
"""

from __future__ import annotations

import asyncio
import contextlib
import mmap
import os
import struct
import sys
import warnings
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Self

import httpx

from mhrc.core.logs import get_logger

if TYPE_CHECKING:  # pragma: no cover
    import xllamacpp

log = get_logger("mhrc.local")

GGUF_MAGIC = b"GGUF"
INSTALL_HINT = 'install it with `pip install -e ".[local]"` or `pip install xllamacpp`'
DEFAULT_CTX_PER_SLOT = 8192
ERRORS_ONLY = 1  # llama.cpp log verbosity: 0 silent, 1 errors, 2 warnings, 3 info (its default), 4 debug
LOOPBACK = "127.0.0.1"
DRAIN_TIMEOUT = 120.0  # seconds stop() waits for in-flight requests (a 1024-token reply at ~10 tokens/s, with room)
_POLL = 0.05  # seconds between /slots polls while draining
_READ_CHUNK = 16 << 20

# Gemma's own template (Google's tokenizer_config.json for Gemma 3): a system message is folded
# into the first user turn, assistant turns are "model" turns.
GEMMA_CHAT_TEMPLATE = """{{ bos_token }}
{%- if messages[0]['role'] == 'system' -%}
    {%- if messages[0]['content'] is string -%}
        {%- set first_user_prefix = messages[0]['content'] + '\\n\\n' -%}
    {%- else -%}
        {%- set first_user_prefix = messages[0]['content'][0]['text'] + '\\n\\n' -%}
    {%- endif -%}
    {%- set loop_messages = messages[1:] -%}
{%- else -%}
    {%- set first_user_prefix = "" -%}
    {%- set loop_messages = messages -%}
{%- endif -%}
{%- for message in loop_messages -%}
    {%- if (message['role'] == 'user') != (loop.index0 % 2 == 0) -%}
        {{ raise_exception("Conversation roles must alternate user/assistant/user/assistant/...") }}
    {%- endif -%}
    {%- if (message['role'] == 'assistant') -%}
        {%- set role = "model" -%}
    {%- else -%}
        {%- set role = message['role'] -%}
    {%- endif -%}
    {{ '<start_of_turn>' + role + '\\n' + (first_user_prefix if loop.first else "") }}
    {%- if message['content'] is string -%}
        {{ message['content'] | trim }}
    {%- elif message['content'] is iterable -%}
        {%- for item in message['content'] -%}
            {%- if item['type'] == 'text' -%}
                {{ item['text'] | trim }}
            {%- endif -%}
        {%- endfor -%}
    {%- endif -%}
    {{ '<end_of_turn>\\n' }}
{%- endfor -%}
{%- if add_generation_prompt -%}
    {{ '<start_of_turn>model\\n' }}
{%- endif -%}
"""

# architecture prefix (general.architecture) -> template for GGUFs that carry none
FALLBACK_TEMPLATES: dict[str, str] = {"gemma": GEMMA_CHAT_TEMPLATE}


class GGUFError(ValueError):
    """A `gguf:PATH` that cannot be served; the message says what to fix (a configuration error)."""


class LocalModelError(RuntimeError):
    """The local model server failed at run time (the file would not load, or it would not stop)."""


def _import_xllamacpp() -> Any:
    try:
        import xllamacpp
    except ImportError as exc:
        raise GGUFError(f"serving a local GGUF model needs the xllamacpp package: {INSTALL_HINT} ({exc})") from None
    return xllamacpp


def check_gguf(path: str | os.PathLike[str]) -> Path:
    """The GGUF file at `path`, or GGUFError saying what to fix.

    Cheap enough for config validation (four bytes read, one import, no model load), so that a
    wrong path fails before an episode starts rather than when its server does."""
    file = Path(path).expanduser()
    if not file.exists():
        raise GGUFError(f"GGUF model {str(path)!r} does not exist: give the path of a .gguf file")
    if not file.is_file():
        raise GGUFError(f"GGUF model {str(path)!r} is not a file (a directory?): give the path of a .gguf file")
    try:
        with file.open("rb") as fh:
            magic = fh.read(len(GGUF_MAGIC))
    except OSError as exc:
        raise GGUFError(f"GGUF model {str(path)!r} cannot be read: {exc.strerror or exc}") from None
    if magic != GGUF_MAGIC:
        raise GGUFError(
            f"{str(path)!r} is not a GGUF file (it does not start with b'GGUF'): give a llama.cpp .gguf model"
        )
    _import_xllamacpp()
    return file


_SCALARS = {0: "<B", 1: "<b", 2: "<H", 3: "<h", 4: "<I", 5: "<i", 6: "<f", 7: "<?", 10: "<Q", 11: "<q", 12: "<d"}
_STRING, _ARRAY = 8, 9


def gguf_metadata(path: str | os.PathLike[str], keys: set[str]) -> dict[str, str | int | float | bool]:
    """The scalar and string values of `keys` in a GGUF file's header (arrays are skipped).

    Reads the header only (~30 ms for a 262k-token vocabulary), so the template can be chosen
    before the model loads. GGUF v2/v3 only (v1, long obsolete, had 32-bit lengths)."""
    out: dict[str, str | int | float | bool] = {}
    try:
        with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as m:
            magic, version, _n_tensors, n_kv = struct.unpack_from("<4sIQQ", m, 0)
            if magic != GGUF_MAGIC:
                raise GGUFError(f"{str(path)!r} is not a GGUF file (it does not start with b'GGUF')")
            if version < 2:
                return out
            pos = 24

            def string(at: int) -> tuple[int, int]:
                """(start, end) of the string whose u64 length is at `at`."""
                (n,) = struct.unpack_from("<Q", m, at)
                if at + 8 + n > len(m):
                    raise ValueError("a string runs past the end of the file")
                return at + 8, at + 8 + n

            for _ in range(n_kv):
                start, pos = string(pos)
                key = m[start:pos].decode("utf-8", "replace")
                (kind,) = struct.unpack_from("<I", m, pos)
                pos += 4
                if kind == _STRING:
                    start, pos = string(pos)
                    if key in keys:
                        out[key] = m[start:pos].decode("utf-8", "replace")
                elif kind == _ARRAY:
                    item, count = struct.unpack_from("<IQ", m, pos)
                    pos += 12
                    if item == _STRING:
                        for _ in range(count):
                            _, pos = string(pos)
                    else:
                        pos += struct.calcsize(_SCALARS[item]) * count
                else:
                    fmt = _SCALARS[kind]
                    if key in keys:
                        out[key] = struct.unpack_from(fmt, m, pos)[0]
                    pos += struct.calcsize(fmt)
                if pos > len(m):
                    raise ValueError("a value runs past the end of the file")
    except GGUFError:
        raise
    except (struct.error, KeyError, ValueError, OSError) as exc:
        raise GGUFError(f"{str(path)!r} has a malformed GGUF header ({exc}): is the file complete?") from None
    return out


def fallback_chat_template(path: str | os.PathLike[str]) -> str | None:
    """A chat template for a GGUF that carries none, else None (its own template is used).

    Without one llama.cpp formats chats as ChatML, which a Gemma model was never trained on."""
    meta = gguf_metadata(path, {"general.architecture", "tokenizer.chat_template"})
    if meta.get("tokenizer.chat_template"):
        return None
    arch = str(meta.get("general.architecture", ""))
    for prefix, template in FALLBACK_TEMPLATES.items():
        if arch.startswith(prefix):
            return template
    log.warning("gguf_without_chat_template", path=str(path), architecture=arch, using="ChatML (llama.cpp's fallback)")
    return None


def _release_freed_memory() -> None:
    """Hand freed heap back to the OS (glibc only).

    Measured: an evaluation worker that starts and stops a server per episode grew ~5 MB per
    episode in RSS that malloc_trim gives back (glibc keeps llama.cpp's freed buffers)."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)


def _prefetch(path: Path) -> None:
    """Read the file once so the GIL-holding load finds it in the page cache (reads release the GIL)."""
    buf = bytearray(_READ_CHUNK)
    with path.open("rb", buffering=0) as fh:
        while fh.readinto(buf):
            pass


class LocalModelServer:
    """llama.cpp's HTTP server for one GGUF file, in this process, on an ephemeral loopback port.

    `slots` is the number of sequences decoded in parallel: one per robot, so that no robot waits
    for another's reply. Each slot has `n_ctx_per_slot` tokens of context (the KV cache holds
    slots * n_ctx_per_slot). `threads` defaults to os.cpu_count(). `seed` is the sampling seed of
    requests that carry none (a request's own `seed` wins). `chat_template` overrides the GGUF's
    (default: its own, or a known one for a GGUF without one, see fallback_chat_template).
    `api_key`, if given, is required as a Bearer token on every request but /health.
    `verbosity` is llama.cpp's log threshold (1: errors only; process-wide).

        async with LocalModelServer(path, slots=3) as srv:
            client = OpenAIChatClient(srv.model, srv.base_url)

    The server has no network access (offline, no web UI, no tools) and listens on 127.0.0.1 only.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        slots: int,
        n_ctx_per_slot: int = DEFAULT_CTX_PER_SLOT,
        threads: int | None = None,
        seed: int | None = None,
        *,
        chat_template: str | None = None,
        api_key: str | None = None,
        verbosity: int = ERRORS_ONLY,
        drain_timeout: float = DRAIN_TIMEOUT,
    ) -> None:
        if slots < 1:
            raise ValueError(f"slots must be at least 1 (one per robot), not {slots}")
        if n_ctx_per_slot < 16:
            raise ValueError(f"n_ctx_per_slot must be at least 16 tokens, not {n_ctx_per_slot}")
        if threads is not None and threads < 1:
            raise ValueError(f"threads must be at least 1, not {threads}")
        if seed is not None and not 0 <= seed < 2**32:
            raise ValueError(f"seed must be in [0, 2**32), not {seed}")
        self.path = Path(path).expanduser()
        self.slots = slots
        self.n_ctx_per_slot = n_ctx_per_slot
        self.threads = threads or os.cpu_count() or 1
        self.seed = seed
        self.chat_template = chat_template
        self.api_key = api_key
        self.verbosity = verbosity
        self.drain_timeout = drain_timeout
        self._server: xllamacpp.Server | None = None
        self._address: str | None = None
        self._model: str | None = None
        self._started = False

    # -- properties -----------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._server is not None

    @property
    def base_url(self) -> str:
        """The OpenAI base URL, `http://127.0.0.1:PORT/v1` (requests go to {base_url}/chat/completions)."""
        return f"{self._require_address()}/v1"

    @property
    def port(self) -> int:
        return int(self._require_address().rsplit(":", 1)[1])

    @property
    def model(self) -> str:
        """What a client should send as "model": the id the server lists at GET /v1/models (the path)."""
        if self._model is None:
            raise LocalModelError("the local model server is not running: await start() first")
        return self._model

    @property
    def headers(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.api_key}"} if self.api_key else {}

    def _require_address(self) -> str:
        if self._address is None or self._server is None:
            raise LocalModelError("the local model server is not running: await start() first")
        return self._address

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> str:
        """Load the model and serve it; returns the base URL. Starting twice is an error.

        The load runs in a worker thread, but xllamacpp holds the GIL while loading, so the
        event loop stalls for the load itself (see the module docstring)."""
        if self._started:
            raise LocalModelError(f"the local model server for {self.path} was already started (one start per server)")
        check_gguf(self.path)  # a config error leaves the server startable once the file is fixed
        template = self.chat_template if self.chat_template is not None else fallback_chat_template(self.path)
        self._started = True
        load = asyncio.ensure_future(asyncio.to_thread(self._load, template))
        try:
            await asyncio.shield(load)
        except asyncio.CancelledError:
            # The load cannot be interrupted: let it finish, then free what it loaded.
            with contextlib.suppress(Exception):
                await load
            await self.stop()
            raise
        except Exception:
            with contextlib.suppress(Exception):
                await self.stop()  # loaded but not ready: free it
            raise
        log.info(
            "local_model_started",
            path=str(self.path),
            url=self.base_url,
            slots=self.slots,
            n_ctx_per_slot=self.n_ctx_per_slot,
            threads=self.threads,
        )
        return self.base_url

    def _params(self, template: str | None) -> Any:
        xlc = _import_xllamacpp()
        p = xlc.CommonParams()
        p.model.path = str(self.path)
        p.n_parallel = self.slots
        p.n_ctx = self.slots * self.n_ctx_per_slot
        p.kv_unified = False  # each slot owns its n_ctx_per_slot: one robot's long prompt cannot starve another's
        p.cpuparams.n_threads = self.threads
        p.cpuparams_batch.n_threads = self.threads
        if self.seed is not None:
            p.sampling.seed = self.seed
        if template is not None:
            p.chat_template = template
        p.use_jinja = True  # already the default: the GGUF's own (Jinja) template, or ours
        p.hostnames = [LOOPBACK]
        p.port = 0  # an ephemeral port: parallel episodes never collide
        p.offline = True  # never download anything
        p.ui = False
        p.endpoint_slots = True  # stop() and start() read /slots
        p.endpoint_metrics = True  # /metrics: tokens decoded in all, for tests and benchmarks (loopback only)
        p.api_keys = [self.api_key] if self.api_key else []
        p.verbosity = self.verbosity
        p.fit_params = False  # a second, trial load to fit GPU memory: doubles the load time on a CPU
        p.cache_ram_mib = 0  # slots == robots, each keeps its own KV cache: no host-RAM prompt cache (8 GiB by default)
        return p

    def _load(self, template: str | None) -> None:
        """In a worker thread: load, then wait for llama.cpp's loop to run (see the module docstring)."""
        xlc = _import_xllamacpp()
        _prefetch(self.path)
        params = self._params(template)
        try:
            server = xlc.Server(params)
        except (RuntimeError, ValueError) as exc:
            raise LocalModelError(
                f"llama.cpp could not load {self.path} ({exc}); run with verbosity=3 to see why"
            ) from None
        self._server = server
        self._address = server.listening_address
        # GET /slots is answered by llama.cpp's main loop: once it answers, the loop runs, and
        # dropping the server can no longer lose the stop signal.
        try:
            with httpx.Client(base_url=server.listening_address, headers=self.headers, timeout=60.0) as http:
                http.get("/slots").raise_for_status()
                models = http.get("/v1/models").raise_for_status().json()
        except httpx.HTTPError as exc:
            raise LocalModelError(f"the local model server for {self.path} loaded but does not answer: {exc}") from None
        data = models.get("data") or [{}]
        self._model = str(data[0].get("id") or self.path)

    async def idle(self) -> bool:
        """True when no slot is decoding (GET /slots)."""
        async with httpx.AsyncClient(base_url=self._require_address(), headers=self.headers, timeout=10.0) as http:
            slots = (await http.get("/slots")).raise_for_status().json()
        return not any(slot.get("is_processing") for slot in slots)

    async def _drain(self) -> None:
        """Wait until no slot decodes, seen twice in a row (a request just received may not hold a slot yet).

        llama.cpp does not cancel a non-streaming request whose client went away (measured: it
        decodes on to max_tokens), so this can take as long as the longest reply in flight."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.drain_timeout
        idle_seen = 0
        while True:
            try:
                idle_seen = idle_seen + 1 if await self.idle() else 0
            except httpx.HTTPError as exc:
                log.warning("local_model_drain_unreadable", path=str(self.path), error=str(exc))
                return  # a server that cannot answer has no request left to answer either
            if idle_seen >= 2:
                return
            if loop.time() >= deadline:
                raise LocalModelError(
                    f"the local model server for {self.path} is still answering after {self.drain_timeout:.0f} s: "
                    "cancel or close its clients, then call stop() again (stopping it now would hang this process)"
                )
            await asyncio.sleep(_POLL)

    async def stop(self) -> None:
        """Stop serving and free the model. Idempotent.

        Waits (up to drain_timeout) for in-flight requests to end first: dropping a busy server
        hangs the process (see the module docstring). Cancel or close the clients before this."""
        if self._server is None:
            return
        await self._drain()
        holder = [self._server]
        self._server = None
        self._address = None
        self._model = None
        # The last reference goes in the worker thread, so ~Server's join runs there.
        await asyncio.to_thread(holder.clear)
        if sys.platform == "linux":
            await asyncio.to_thread(_release_freed_memory)
        log.info("local_model_stopped", path=str(self.path))

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.stop()

    def __del__(self) -> None:
        if getattr(self, "_server", None) is not None:
            warnings.warn(
                f"LocalModelServer for {self.path} was not stopped: await stop()", ResourceWarning, stacklevel=1
            )

    def __repr__(self) -> str:
        where = (self._address or "stopped") if self._started else "not started"
        return f"LocalModelServer({str(self.path)!r}, slots={self.slots}, {where})"
