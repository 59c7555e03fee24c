"""The screenshot of Rerun's web viewer on docs/seeing.md, made from a real recording, headless.

Runs `mhrc show TRACE --rerun serve` (the web viewer on 127.0.0.1), opens its address in headless
chromium (scripts/install-browser.sh) with every host name but loopback unresolvable, so the page
cannot reach the network (the web viewer's own analytics included), waits for the recording to
load and saves a PNG.

    python scripts/rerun_screenshot.py TRACE docs/img/rerun_viewer.png [--wait 40]
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.service import Service


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("trace", type=Path)
    ap.add_argument("png", type=Path)
    ap.add_argument("--wait", type=float, default=40.0, help="seconds for the viewer to load and draw")
    args = ap.parse_args()
    served = subprocess.Popen(
        [sys.executable, "-m", "mhrc", "show", str(args.trace), "--rerun", "serve"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert served.stdout is not None
        address = served.stdout.readline().strip().removeprefix("rerun: ")
        if not address.startswith("http://127.0.0.1:"):
            raise SystemExit(f"mhrc show --rerun serve printed {address!r}, not the viewer's address")
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for arg in (
            "--headless=new",
            "--no-sandbox",
            "--disable-dev-shm-usage",
            "--enable-unsafe-swiftshader",
            "--use-angle=swiftshader",
            "--ignore-gpu-blocklist",
            "--window-size=1600,1000",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
        ):
            options.add_argument(arg)
        driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        try:
            driver.get(address)
            time.sleep(args.wait)
            args.png.parent.mkdir(parents=True, exist_ok=True)
            driver.save_screenshot(str(args.png))
        finally:
            driver.quit()
    finally:
        served.send_signal(signal.SIGINT)
        served.wait(30)
    print(args.png)


if __name__ == "__main__":
    main()
