"""Run benchmarks: ``python -m bench`` (all) or ``python -m bench NAME [ARGS]``."""

import importlib
import sys

BENCHMARKS = ("plan", "acquire", "accuracy", "solvers", "handeye", "honesty", "budget", "unmodelled", "render",
              "cluster", "storage", "ground_truth", "evaluate", "pnp", "identity", "model_cards", "pipeline",
              "ransac_noise", "stranger_model", "trajectory", "tracking", "threads", "targets", "detector",
              "paper_table", "facility", "image_costs")
#: need arguments or take long; not part of `python -m bench`
ON_REQUEST = ("identity", "model_cards", "pipeline", "ransac_noise", "stranger_model", "tracking", "threads", "targets",
              "detector", "paper_table", "image_costs")

if __name__ == "__main__":
    names = sys.argv[1:2] or [name for name in BENCHMARKS if name not in ON_REQUEST]
    for name in names:
        if name not in BENCHMARKS:
            sys.exit(f"unknown benchmark {name!r}; available: {', '.join(BENCHMARKS)}")
        module = importlib.import_module(f"bench.{name}")
        module.main(*sys.argv[2:])
