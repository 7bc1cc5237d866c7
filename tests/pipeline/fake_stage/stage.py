"""A stand-in for a stage whose workers finish in any order (tests/pipeline/test_integrity.py):
it writes the smoke plan's rows in the order ``FAKE_ORDER_SEED`` shuffles them to, and is
"killed" (KeyboardInterrupt) after ``FAKE_STOP_AFTER`` rows when that is set."""

import os

import numpy as np

from core.config import Config
from manifests import Workspace, open_sink, read_keys
from stages.plan.stage import plan_sample, planned_samples
from stages.plan.stage import resolve as resolve  # the plan's inputs and outputs


def run(config: Config, workspace: Workspace) -> None:
    ids = planned_samples(config)
    order = np.random.default_rng(int(os.environ.get("FAKE_ORDER_SEED", "0"))).permutation(len(ids))
    stop = int(os.environ.get("FAKE_STOP_AFTER", "-1"))
    done = read_keys(workspace, "plan")
    with open_sink(workspace, "plan", config.run.part_rows) as sink:
        for count, index in enumerate(order):
            if count == stop:
                raise KeyboardInterrupt
            if ids[index][2] not in done:
                sink.add(plan_sample(config, *ids[index]))
