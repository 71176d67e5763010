"""The interactive session (the TUI's engine) leaves each node in the NMT state it found.

A node that starts OPERATIONAL by itself with its heartbeat off (CANopenNode's defaults) must
not end PRE-OPERATIONAL: on a vehicle its PDOs would stop for every other consumer.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.wiring import demo_settings, open_devices
from canimucal.sim.truth import Truth

NODE = 0x10


@pytest.mark.parametrize(
    ("behaviour", "found"),
    [
        ({"nmt_start": "operational", "heartbeat_ms": 0}, "OPERATIONAL"),
        ({}, "PRE-OPERATIONAL"),
    ],
)
def test_session_leaves_the_node_as_found(
    tmp_path: Path, behaviour: dict[str, object], found: str
) -> None:
    d = Truth.random(np.random.default_rng(8), cross_axis_max=0.0).to_dict() | behaviour
    with open_devices(demo_settings([Truth.from_dict(d)], time_scale=10.0, seed=3)) as rig:
        session = rig.session(
            builtin_plan("two"), tmp_path, plan_name="two", averaging=AveragingPolicy(fixed_s=2.0)
        )
        session.start()
        for _ in range(30):  # half a second of samples flowing
            session.poll()
            time.sleep(0.015)
        assert rig.sim_nodes[NODE].nmt_state == "OPERATIONAL"  # streaming
        session.finish()
        client = rig.clients[NODE]
        client.close()  # what quitting the TUI (or SIGTERM) runs for each client
        assert client.nmt_found is not None and client.nmt_found.state == found
        time.sleep(0.1)
        assert rig.sim_nodes[NODE].nmt_state == found
