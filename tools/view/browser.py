"""The live view's page in a real headless browser: Debian's chromium driven by playwright (no
browser download), for the tests, ``aider-exo bench view`` and the README's screenshot.

The page keeps what it measured in ``window.viewStats`` (static/view.js): the updates it drew,
each update's latency from the newest frame's bus timestamp to its arrival in the page, and the
gait states it showed in order."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from config.errors import AiderError

#: chromium's flags for a headless page in a container: no sandbox (root), no GPU, and none of
#: the background traffic that would try to reach the network
CHROMIUM_ARGS = ("--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-dev-shm-usage")
VIEWPORT = {"width": 1200, "height": 1000}


def chromium_path() -> str | None:
    """Debian's chromium (``apt-get install chromium``, as ``make test`` does), if installed."""
    return shutil.which("chromium") or ("/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)


def missing() -> str | None:
    """Why a browser cannot be driven here (None: it can)."""
    if chromium_path() is None:
        return "chromium is not installed (apt-get install chromium; make test installs it as root)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install -e '.[test]')"
    return None


def stat_fields(path: str | Path) -> list[str] | None:
    """The fields of a ``/proc/.../stat`` file after "pid (name) " (field 0 is the state), or None
    when the process or thread has ended."""
    try:
        text = Path(path).read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def cpu_s(stat_path: str | Path) -> float:
    """CPU time (user + system, s) of the process or thread whose ``/proc/.../stat`` is ``stat_path``."""
    fields = stat_fields(stat_path)
    return 0.0 if fields is None else (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _descendants(pid: int) -> list[int]:
    """The processes under ``pid`` (from ``/proc``: each one's parent)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        fields = stat_fields(stat)
        if fields is not None:
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


class Browser:
    """One headless chromium with one page on ``url``; a context manager. ``nice``: the browser's
    processes at that niceness (the page's drawing yields the CPU to a walk on the same machine)."""

    def __init__(self, url: str, *, nice: int = 0) -> None:
        self.url, self.nice = url, nice
        self._pw: Any = None
        self._browser: Any = None
        self.page: Any = None

    def __enter__(self) -> Browser:
        why = missing()
        if why:
            raise AiderError(f"cannot drive a browser: {why}")
        from playwright.sync_api import sync_playwright

        self._pw = sync_playwright().start()
        try:
            self._browser = self._pw.chromium.launch(executable_path=chromium_path(), headless=True, args=list(CHROMIUM_ARGS))
            self.page = self._browser.new_page(viewport=VIEWPORT)
            self.page.goto(self.url)
            if self.nice:
                for pid in _descendants(os.getpid()):
                    try:
                        os.setpriority(os.PRIO_PROCESS, pid, self.nice)
                    except OSError:  # gone already
                        pass
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._browser is not None:
            self._browser.close()
        if self._pw is not None:
            self._pw.stop()

    def stats(self) -> dict[str, Any]:
        """The page's ``window.viewStats``: updates, latencies (s), the gait states it showed."""
        return self.page.evaluate("() => window.viewStats")

    def text(self, selector: str) -> str:
        return self.page.inner_text(selector)

    def data(self, selector: str, name: str) -> str | None:
        """A ``data-*`` attribute of an element (the canvases say what they drew)."""
        return self.page.get_attribute(selector, f"data-{name}")

    def wait_for(self, js: str, timeout_s: float) -> None:
        """Until the page's JavaScript expression ``js`` is true (a playwright timeout error after ``timeout_s``)."""
        self.page.wait_for_function(js, timeout=timeout_s * 1000)

    def screenshot(self, path: Path) -> Path:
        """The page as a PNG at ``path`` (written atomically: config.files)."""
        from config.files import write_bytes

        return write_bytes(path, self.page.screenshot(full_page=True))
