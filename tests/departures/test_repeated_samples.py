"""A sensor logged faster than it samples: σ from the unique samples (issue 21 item 10).

The logger polls four times per sample and writes the held value (75 % of the rows repeat
the one before in every channel while ``t`` and the counter run). ``solve`` finds it, says
so in one line and takes n and σ from the unique samples: over seeds 0–19 dealt round the
five and recommended plans at exact and 0.1° poses (10 s positions, the sensor at 100 Hz)
the rms of (estimate − truth)/σ lies within 0.8–1.25 and each parameter's Σz²/n within its
χ² band (measured: 0.84, largest |z| 2.4). Taken as they are, the held rows make each mean's
within-position σ 2× too small; the pose-scatter estimate then soaks up the missing noise
and, priced for its own uncertainty, overshoots: rms 0.68, outside the band. ``analyze`` of
such a file names nothing on a clean unit and says what it found in one line.
"""

from __future__ import annotations

from canimucal.analysis.report import analyze
from canimucal.analysis.solve import solve_recording
from tests.support import departures as dep

SEEDS = tuple(range(20))


def test_solve_prices_the_unique_samples() -> None:
    pairs = dep.rotation(dep.REPEATED, SEEDS)
    spread = dep.spread_of([dep.recording_errors(case, seed) for case, seed in pairs])
    assert not spread.within(), (spread.rms, spread.within())
    case, seed = pairs[0]
    notes = solve_recording(dep.short_recording(case, seed)).notes
    assert any(
        "75 % of samples repeat the previous one: effective rate ~100 Hz" in n for n in notes
    )


def test_analyze_names_nothing_on_a_clean_held_unit() -> None:
    for case, seed in dep.rotation(dep.REPEATED, (0, 1))[:2]:
        a = analyze(dep.short_recording(case, seed))
        assert not a.result.findings, [f.effect for f in a.result.findings]
        assert any("repeat the previous one" in n for n in a.notes), a.notes
