"""``stand bench view``: what the operator page costs and how fast it answers.

* the loop's speed with and without an open live page: the default scenario as fast as possible, alternately
  with no observer and with ``--view``'s live feed and server and a page open in headless Chromium (or, where
  Chromium is not installed, a websocket client that decodes every push, and the row says so); the best of
  several runs each, since this machine's load moves single runs by 10-30 %;
* the page's update rate during a live run (pushes received and redraws per second of wall time);
* the time to first draw of a replay of the default run (from the page's navigation start to its first full
  drawing, the server deriving the sky for the whole run included).
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

#: The slowdown the page may cost the loop, percent (the issue's limit).
LIMIT_PERCENT = 5.0


class Browser:
    """Headless Chromium through selenium, or None when either is missing."""

    @staticmethod
    def missing() -> str | None:
        """What keeps the bench from opening a page in Chromium (None: nothing), named as the user fixes it."""
        try:
            import selenium  # noqa: F401 - only whether it is installed
        except ImportError:
            return "no selenium (pip install 'selenium>=4.51,<5', or the test extra)"
        if not (shutil.which("chromium") or shutil.which("chromium-browser")):
            return "no Chromium (chromium or chromium-browser on the PATH)"
        if not shutil.which("chromedriver"):
            return "no chromedriver on the PATH (Debian: chromium-driver)"
        return None

    @staticmethod
    def open():
        if Browser.missing() is not None:
            return None
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        chromium = shutil.which("chromium") or shutil.which("chromium-browser")
        driver = shutil.which("chromedriver")
        profile = tempfile.mkdtemp(prefix="stand-bench-chromium-")
        opts = webdriver.ChromeOptions()
        opts.binary_location = chromium
        for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                     "--window-size=1600,1400"):
            opts.add_argument(flag)
        d = webdriver.Chrome(service=Service(driver), options=opts)
        d.set_page_load_timeout(60)
        d._stand_profile = profile
        return d

    @staticmethod
    def close(d) -> None:
        if d is not None:
            d.quit()
            shutil.rmtree(d._stand_profile, ignore_errors=True)


def _wait(d, script: str, timeout_s: float = 60.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        v = d.execute_script(script)
        if v:
            return v
        time.sleep(0.05)
    raise TimeoutError(f"the page did not answer {script!r} within {timeout_s:g} s")


class SocketPage:
    """Stands in for a page where there is no browser: a websocket client that decodes every push."""

    def __init__(self, url: str):
        self.url = url.replace("http://", "ws://") + "ws"
        self.messages = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self):
        import aiohttp

        async with aiohttp.ClientSession() as s, s.ws_connect(self.url) as ws:
            while not self._stop.is_set():
                try:
                    msg = await ws.receive(timeout=0.2)
                except TimeoutError:
                    continue
                if msg.type != aiohttp.WSMsgType.TEXT:
                    break
                json.loads(msg.data)
                self.messages += 1

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5.0)


def _descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += children.get(p, [])
    return out


def _cpu_s(pids) -> float:
    """User plus system CPU seconds of these processes so far (Linux /proc; 0 for those gone)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0
    for p in pids:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += int(fields[11]) + int(fields[12])
    return total / tick


def _pin(pids, cpus: set[int]) -> None:
    for p in pids:
        try:
            os.sched_setaffinity(p, cpus)
        except OSError:
            pass  # a process that already ended


def _run_once(sc, out: Path, browser, with_page: bool, pin: bool = False) -> tuple[float, dict]:
    """Wall time of one run, and what the page saw; ``loop_cpu_s`` is the loop thread's own CPU time, which the
    other processes on a shared machine do not inflate."""
    from stand.compose import build
    from stand.loop import run
    from stand.view.server import LiveSession

    stats: dict = {}
    with build(sc) as scene:
        out.mkdir(parents=True)
        live = page = None
        if with_page:
            live = LiveSession("127.0.0.1", 0, None)
            url = live.start(sc, out)
            if browser is not None:
                browser.get(url)
                _wait(browser, "return !!(window.standView && window.standView.loaded)")
            else:
                page = SocketPage(url)
                time.sleep(0.5)
            if pin:  # the page on the second core, the loop on the first
                _pin([live.process.pid], {1})
                if browser is not None:
                    _pin(_descendants(browser.service.process.pid), {1})
        page_pids = []
        if live is not None:
            page_pids = [live.process.pid] + (_descendants(browser.service.process.pid) if browser is not None else [])
        p0, s0 = _cpu_s(page_pids), _cpu_s(page_pids[:1])
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            run(scene, out, progress=False, observer=live.observer if live else None)
        finally:
            wall = time.perf_counter() - t0
            stats["loop_cpu_s"] = time.thread_time() - c0
            stats["page_cpu_s"] = _cpu_s(page_pids) - p0
            stats["server_cpu_s"] = _cpu_s(page_pids[:1]) - s0
            if live is not None:
                live.close()
                stats["pushes_sent"] = live.feed.pushes
                stats["sender_cpu_s"] = live.feed.cpu_s
                stats["rows"] = live.feed.rows_taken
                if browser is not None:
                    s = browser.execute_script("const s = window.standView.stats; return {pushes: s.pushes, "
                                               "draws: s.draws, last_draw_ms: s.lastDrawMs}")
                    stats.update(s)
                else:
                    stats["pushes"] = page.messages
                    page.close()
    return wall, stats


def _compare(sc, tmp: Path, browser, reps: int, pin: bool, duration: float) -> tuple[list[dict], list[dict]]:
    walls: dict[bool, list[float]] = {False: [], True: []}
    cpus: dict[bool, list[float]] = {False: [], True: []}
    stats: list[dict] = []
    for k in range(reps):
        for with_page in (False, True) if k % 2 == 0 else (True, False):
            wall, st = _run_once(sc, tmp / f"r{int(pin)}-{k}-{int(with_page)}", browser, with_page, pin)
            walls[with_page].append(wall)
            cpus[with_page].append(st["loop_cpu_s"])
            if with_page:
                stats.append({**st, "wall_s": wall})
    base, page = min(walls[False]), min(walls[True])
    slow = 100.0 * (page / base - 1.0)
    tag = "pinned" if pin else "shared"
    where = ("the loop on core 0, the page's server and browser on core 1" if pin else
             "every process on any core")
    rows = [
        {"name": f"view.loop.{tag}.without_page.realtime_factor", "value": round(duration / base, 1), "unit": "x",
         "note": f"{where}; {duration:g} s of the default scenario in {base:.2f} s (best of {reps})"},
        {"name": f"view.loop.{tag}.with_page.realtime_factor", "value": round(duration / page, 1), "unit": "x",
         "note": f"{page:.2f} s (best of {reps})"},
        {"name": f"view.loop.{tag}.slowdown", "value": round(slow, 2), "unit": "%", "limit": f"<= {LIMIT_PERCENT:g}",
         "pass": slow <= LIMIT_PERCENT, "full_only": True,
         "note": "wall time, best of each; all runs: without " + ", ".join(f"{w:.2f}" for w in walls[False])
                 + " s; with " + ", ".join(f"{w:.2f}" for w in walls[True]) + " s"},
    ]
    if not pin:
        cpu_slow = 100.0 * (min(cpus[True]) / min(cpus[False]) - 1.0)
        rows.append({"name": "view.loop.cpu_slowdown", "value": round(cpu_slow, 2), "unit": "%",
                     "limit": f"<= {LIMIT_PERCENT:g}", "pass": cpu_slow <= LIMIT_PERCENT, "full_only": True,
                     "note": "the loop thread's own CPU time, best of each: " + f"{min(cpus[False]):.2f} s without, "
                             f"{min(cpus[True]):.2f} s with the page"})
    return rows, stats


def bench_view(quick: bool = False) -> list[dict]:
    import dataclasses

    from stand.scenario import DEFAULT_SCENARIO, load

    sc = load(DEFAULT_SCENARIO)
    duration = 600.0 if quick else sc.duration_s
    sc = dataclasses.replace(sc, duration_s=duration)
    reps = 2 if quick else 4
    browser, missing = Browser.open(), Browser.missing()
    rows: list[dict] = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            who = "a page open in headless Chromium" if browser is not None else \
                f"a websocket client decoding every push ({missing or 'the browser did not open'})"
            rows.append({"name": "view.page", "value": "chromium" if browser is not None else "websocket",
                         "note": f"the loop runs with --view's feed and server and {who}"})
            rows_shared, stats = _compare(sc, Path(tmp), browser, reps, False, duration)
            rows += rows_shared
            if hasattr(os, "sched_setaffinity") and len(os.sched_getaffinity(0)) >= 2:
                mask = os.sched_getaffinity(0)
                os.sched_setaffinity(0, {0})
                try:
                    rows += _compare(sc, Path(tmp), browser, reps, True, duration)[0]
                finally:
                    os.sched_setaffinity(0, mask)
            rows += _in_process(stats)
            best = min(stats, key=lambda s: s["wall_s"])
            rows.append({"name": "view.live.pushes_per_s", "value": round(best.get("pushes", 0) / best["wall_s"], 2),
                         "unit": "1/s", "note": f"{best.get('pushes', 0)} pushes received by the page over "
                         f"{best['wall_s']:.2f} s (the feed sends at most 10 per second)"})
            rows.append({"name": "view.page.cpu_share", "value": round(100 * best["page_cpu_s"] / best["wall_s"], 1),
                         "unit": "% core", "note": f"CPU of the server process and the browser during the run: "
                         f"{best['page_cpu_s']:.2f} s over {best['wall_s']:.2f} s, of which the server "
                         f"{best['server_cpu_s']:.2f} s"})
            if browser is not None:
                rows.append({"name": "view.live.redraws_per_s", "value": round(best["draws"] / best["wall_s"], 2),
                             "unit": "1/s", "note": f"last full redraw took {best['last_draw_ms']:.1f} ms"})
            rows += _first_draw(sc, Path(tmp), browser, missing)
    finally:
        Browser.close(browser)
    return rows


def _in_process(stats: list[dict]) -> list[dict]:
    """What the live view costs inside the run's process, measured so that other programs on the machine do
    not blur it: the price of ``record`` and ``poll_control`` per call (best of five million-call loops) times
    the calls of a run, plus the CPU time of the sender thread, against the loop thread's CPU time."""
    from stand.view.state import LiveFeed

    class Null:
        def send(self, message):
            pass

        def receive(self):
            return []

    feed = LiveFeed(Null(), {"duration_s": 5677.0, "record_rate_hz": 10.0})
    row = tuple(float(x) for x in range(30))
    per_record = per_poll = math.inf
    for _ in range(5):
        feed.rows.clear()
        t0 = time.perf_counter()
        for k in range(1_000_000):
            feed.record(k, row)
        per_record = min(per_record, (time.perf_counter() - t0) / 1e6)
        t0 = time.perf_counter()
        for _ in range(1_000_000):
            feed.poll_control()
        per_poll = min(per_poll, (time.perf_counter() - t0) / 1e6)
    feed.rows.clear()
    best = min(stats, key=lambda s: s["loop_cpu_s"])
    calls_s = best["rows"] * per_record
    share = 100.0 * (calls_s + best["sender_cpu_s"]) / best["loop_cpu_s"]
    return [
        {"name": "view.feed.record_ns", "value": round(per_record * 1e9, 1), "unit": "ns",
         "note": f"per row; poll_control {per_poll * 1e9:.1f} ns per call, at most 4 calls per second"},
        {"name": "view.feed.in_process_cost", "value": round(share, 2), "unit": "%", "limit": f"<= {LIMIT_PERCENT:g}",
         "pass": share <= LIMIT_PERCENT, "full_only": True,
         "note": f"{best['rows']} rows recorded ({calls_s * 1e3:.1f} ms) and the sender thread's "
                 f"{best['sender_cpu_s'] * 1e3:.0f} ms of CPU, against the loop thread's {best['loop_cpu_s']:.2f} s"},
    ]


def _first_draw(sc, tmp: Path, browser, missing: str | None = None) -> list[dict]:
    from stand.compose import build
    from stand.loop import run
    from stand.view.server import ReplaySource, ViewServer
    from stand.view.state import write_view_json

    out = tmp / "replay"
    with build(sc) as scene:
        out.mkdir()
        write_view_json(sc, out)
        run(scene, out, progress=False)
    if browser is None:
        return [{"name": "view.replay.first_draw_ms", "value": "n/a", "unit": "ms",
                 "note": f"needs a page in headless Chromium: {missing or 'the browser did not open'}"}]
    times = []
    for _ in range(3):
        with ViewServer(ReplaySource(out)) as view:
            browser.get("about:blank")
            browser.get(view.url)
            ms = _wait(browser, "return window.standView && window.standView.stats.firstDrawMs")
            n = browser.execute_script("return window.standView.store.n")
            times.append(ms)
    return [{"name": "view.replay.first_draw_ms", "value": round(min(times), 0), "unit": "ms",
             "note": f"replay of {sc.duration_s:g} s of the default scenario ({n} samples), navigation start to "
                     f"the first full drawing; runs " + ", ".join(f"{t:.0f}" for t in times) + " ms"}]
