import os
import signal

from mhrc.core.lifeline import PARENT_ENV

if os.environ.get(PARENT_ENV):  # a child of mhrc up --processes: a terminal's Ctrl-C is its parent's to act on
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops it with SIGTERM, in order, and says it once

from mhrc.cli import main  # noqa: E402

main()
