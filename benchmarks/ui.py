"""UI benchmark (issue 4, item 5): CPU of the UI process and key-press-to-repaint latency.

For each output data rate (200 Hz and 1 kHz) the TUI runs in a real 80×24 terminal (a
detached tmux session) against the in-process simulated node at real time (time_scale 1),
with a live session: warm-up skipped, the level pose confirmed, then averaging a 60 s
position while the measurement window (12 s) runs. During the window a benchmark key is
pressed every 0.25 s (posted into the app as a key event); its action changes the notice
line, and the latency is the time from posting the key to the end of the next frame written
to the terminal. CPU is read from /proc for the whole process (UI + I/O worker + simulated
node + CAN threads) and for the UI (main) thread alone.

Targets at 1 kHz: UI ≤ 30 % of one core, p95 latency < 100 ms.

    python benchmarks/ui.py                 # both rates, prints the figures
    python benchmarks/ui.py --rates 1000    # one rate
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WINDOW_S = 12.0
KEY_PERIOD_S = 0.25
POSITION_S = 60.0
CPU_TARGET_PCT = 30.0
P95_TARGET_MS = 100.0


def _thread_cpu_s(tid: int) -> float:
    fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _threads_cpu_s() -> dict[str, float]:
    """CPU seconds of every live Python thread, by name (same names summed)."""
    out: dict[str, float] = {}
    for thread in threading.enumerate():
        if thread.native_id is None:
            continue
        try:
            cpu = _thread_cpu_s(thread.native_id)
        except OSError:
            continue
        name = thread.name.split("(")[0].rstrip("-0123456789 ") or thread.name
        out[name] = out.get(name, 0.0) + cpu
    return out


def _child(rate_hz: int, result_path: Path) -> None:
    from textual.binding import Binding

    from canimucal.model.vocabulary.plans import builtin_plan
    from canimucal.procedure.machine import Phase
    from canimucal.sim.truth import Truth
    from canimucal.tui.app import CalibrationApp
    from canimucal.tui.screens.position import PositionScreen
    from canimucal.tui.source import DeviceSource, NodeStatus, demo_source

    class RateSource(DeviceSource):
        def connect(self) -> list[NodeStatus]:
            super().connect()
            assert self.devices is not None
            for client in self.devices.clients.values():
                client.set_output_data_rate(rate_hz)
            return super().connect()

    class BenchApp(CalibrationApp):
        BINDINGS = [*CalibrationApp.BINDINGS, Binding("x", "bench_key", "bench", show=False)]

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.pressed_at: float | None = None
            self.acted = False
            self.latencies_s: list[float] = []
            self.presses = 0

        def action_bench_key(self) -> None:
            self.presses += 1
            self.screen.query_one("#notice").update(f"benchmark key {self.presses}")  # type: ignore[attr-defined]
            self.acted = True

        def _display(self, screen: Any, renderable: Any) -> None:
            super()._display(screen, renderable)
            if renderable is not None and self.acted and self.pressed_at is not None:
                self.latencies_s.append(time.perf_counter() - self.pressed_at)
                self.pressed_at, self.acted = None, False

    out = Path(tempfile.mkdtemp(prefix="canimucal-ui-bench-"))
    truth = Truth.random(np.random.default_rng(7), cross_axis_max=0.0)
    demo = demo_source([truth], out, time_scale=1.0, seed=7, seconds=POSITION_S)
    source = RateSource(
        demo.settings,
        out,
        demo.description,
        backup_dir=demo.backup_dir,
        overwrite=True,
        seconds=POSITION_S,
    )
    plans = {"five": builtin_plan("five")}
    app = BenchApp(source, plans, plan_name="five")

    async def wait(condition: Any, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                raise TimeoutError("the benchmark flow stalled")
            await asyncio.sleep(0.05)

    async def drive() -> None:
        await wait(lambda: app.screen.check_action("next", ()) is True)
        app.simulate_key("enter")
        await wait(lambda: type(app.screen).__name__ == "PlanScreen")
        app.simulate_key("enter")
        await wait(lambda: isinstance(app.screen, PositionScreen))
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await wait(lambda: screen.phase is Phase.WARMUP)
        app.simulate_key("w")
        await wait(lambda: screen.phase is Phase.INSTRUCT)
        app.simulate_key("enter")
        await wait(lambda: screen.phase is Phase.AVERAGING)
        await asyncio.sleep(1.0)
        main_tid = threading.main_thread().native_id
        assert main_tid is not None
        threads0 = _threads_cpu_s()
        cpu0, ui0, wall0 = time.process_time(), _thread_cpu_s(main_tid), time.perf_counter()
        while time.perf_counter() - wall0 < WINDOW_S:
            app.pressed_at, app.acted = time.perf_counter(), False
            app.simulate_key("x")
            await asyncio.sleep(KEY_PERIOD_S)
        wall = time.perf_counter() - wall0
        lat_ms = np.array(app.latencies_s) * 1e3
        live = next(iter(screen.live.values()), None)
        threads1 = _threads_cpu_s()
        per_thread = {
            k: round(100.0 * (v - threads0.get(k, 0.0)) / wall, 1) for k, v in threads1.items()
        }
        result = {
            "threads_cpu_pct": dict(sorted(per_thread.items(), key=lambda kv: -kv[1])),
            "rate_hz": rate_hz,
            "window_s": wall,
            "process_cpu_pct": 100.0 * (time.process_time() - cpu0) / wall,
            "ui_thread_cpu_pct": 100.0 * (_thread_cpu_s(main_tid) - ui0) / wall,
            "keys": app.presses,
            "repaints_measured": len(lat_ms),
            "latency_p50_ms": float(np.percentile(lat_ms, 50)),
            "latency_p95_ms": float(np.percentile(lat_ms, 95)),
            "latency_max_ms": float(lat_ms.max()),
            "phase_at_end": screen.phase,
            "lost_samples": None if live is None else live.lost_total,
        }
        result_path.write_text(json.dumps(result))
        app.exit(0)

    async def start_driver() -> None:
        app.run_worker(drive(), exclusive=False, exit_on_error=True)

    app.call_after_refresh(lambda: asyncio.ensure_future(start_driver()))
    try:
        app.run()
    finally:
        source.close()
        shutil.rmtree(out, ignore_errors=True)


def _run_in_tmux(rate_hz: int) -> dict[str, Any]:
    tmux = shutil.which("tmux")
    if tmux is None:
        raise SystemExit("benchmarks/ui.py needs tmux (a real terminal for the TUI)")
    result = Path(tempfile.mkdtemp()) / "result.json"
    name = f"canimucal-ui-bench-{uuid.uuid4().hex[:8]}"
    command = (
        f"cd {ROOT} && {sys.executable} {Path(__file__).resolve()} --child "
        f"--rates {rate_hz} --result {result} 2>{result}.err"
    )
    subprocess.run([tmux, "new-session", "-d", "-s", name, "-x", "80", "-y", "24", command])
    try:
        deadline = time.monotonic() + 150.0
        while not result.exists():
            alive = subprocess.run([tmux, "has-session", "-t", name], capture_output=True)
            if time.monotonic() > deadline or alive.returncode != 0:
                err = Path(f"{result}.err")
                raise SystemExit(f"no result at {rate_hz} Hz: {err.read_text()[-2000:]}")
            time.sleep(0.5)
        time.sleep(0.2)
        return dict(json.loads(result.read_text()))
    finally:
        subprocess.run([tmux, "kill-session", "-t", name], capture_output=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", type=int, nargs="+", default=[200, 1000])
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--result", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args.rates[0], args.result)
        return
    print(
        f"UI benchmark: 80×24 terminal (tmux), live session, {WINDOW_S:g} s window, "
        f"a key every {KEY_PERIOD_S:g} s"
    )
    print(
        f"{'rate':>6} {'process CPU':>12} {'UI thread':>10} {'p50 ms':>8} {'p95 ms':>8} "
        f"{'max ms':>8} {'keys':>5} {'lost':>5}"
    )
    for rate in args.rates:
        r = _run_in_tmux(rate)
        print(
            f"{r['rate_hz']:>4} Hz {r['process_cpu_pct']:>11.1f}% {r['ui_thread_cpu_pct']:>9.1f}% "
            f"{r['latency_p50_ms']:>8.1f} {r['latency_p95_ms']:>8.1f} {r['latency_max_ms']:>8.1f} "
            f"{r['repaints_measured']:>5} {r['lost_samples']!s:>5}"
        )
        print(
            "       per thread (CPU %): "
            + ", ".join(f"{k} {v:g}" for k, v in list(r["threads_cpu_pct"].items())[:6])
        )
        if r["rate_hz"] == 1000:
            ok_cpu = r["ui_thread_cpu_pct"] <= CPU_TARGET_PCT
            ok_lat = r["latency_p95_ms"] < P95_TARGET_MS
            print(
                f"targets at 1 kHz: UI CPU ≤ {CPU_TARGET_PCT:g} % "
                f"{'met' if ok_cpu else 'MISSED'}; p95 < {P95_TARGET_MS:g} ms "
                f"{'met' if ok_lat else 'MISSED'}"
            )


if __name__ == "__main__":
    main()
