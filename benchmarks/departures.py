"""The departures suite over 40 seeds (issue 21; tests/departures/ runs fewer).

For each departure of ``tests/support/departures.py`` on the five and recommended plans,
exact and 0.1° poses: how often ``analyze`` names the departure's own cause alone, how often
it names another (a wrong cause; designed rate 1 %), how often a pair is ambiguous, and
``solve``'s spread of (estimate − truth)/σ (rms, the largest |z|, and the parameters whose
Σz²/n leave their χ² band) where ``solve``'s model holds the departure.

    python benchmarks/departures.py [--seeds 40] [--departures tilted_base,cross_axis]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.support

from tests.support import departures as dep  # noqa: E402

DEPARTURES = {
    d.name: d for d in (dep.Departure("clean"), dep.TILTED_BASE, dep.CROSS_AXIS, dep.QUADRATIC)
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40, help="seeds 0..N-1 (default 40)")
    parser.add_argument("--departures", default=",".join(DEPARTURES), help="comma-separated")
    parser.add_argument("--no-analyze", action="store_true", help="only solve's spread")
    args = parser.parse_args()
    seeds = tuple(range(args.seeds))
    for name in args.departures.split(","):
        for case in dep.grid(DEPARTURES[name], seeds):
            t0 = time.perf_counter()
            line = f"{case.label:36s}"
            if case.plan in case.departure.solvable:
                s = dep.spread(case)
                bad = s.within(comparisons=4)
                line += f" solve rms z {s.rms:.3f} max |z| {s.largest:.2f}"
                line += f" {'ok' if not bad else 'OUT: ' + '; '.join(bad)}"
            else:
                line += " solve: the model cannot hold it"
            if not args.no_analyze:
                alone = wrong = ambiguous = 0
                for seed in seeds:
                    causes, amb = dep.named(case, seed)
                    alone += causes == case.departure.causes
                    wrong += bool(causes - case.departure.causes)
                    ambiguous += amb
                line += (
                    f" | analyze alone {alone}/{len(seeds)}, wrong {wrong}, ambiguous {ambiguous}"
                )
            print(f"{line} [{time.perf_counter() - t0:.0f} s]", flush=True)


if __name__ == "__main__":
    main()
