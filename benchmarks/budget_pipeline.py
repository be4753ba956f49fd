#!/usr/bin/env python3
"""The ``pipeline`` executable with its reconstruction held to a memory budget (benchmark harness).

Until the reconstruction stage takes ``max_memory_mb`` as a parameter, this
runs :mod:`subpix_ros.nodes.pipeline` with the reconstruction node's
``reconstruct_aligned`` replaced, in this process only, by
:func:`subpix_ros.core.superres_budget.reconstruct_within_budget` with
``max_memory_mb`` from the environment variable ``SUBPIX_BENCH_MAX_MEMORY_MB``
(the plan of each set is printed to stderr). Used by bench_pipeline.py and
soak.py ``--max-memory-mb``; arguments as for the pipeline.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from subpix_ros.core.superres_budget import reconstruct_within_budget  # noqa: E402
from subpix_ros.nodes import pipeline, reconstruction_node  # noqa: E402

BUDGET = float(os.environ["SUBPIX_BENCH_MAX_MEMORY_MB"])


def _within_budget(frames, shifts, factor, masks=None, **kw):
    res, plan = reconstruct_within_budget(frames, shifts, factor, masks=masks, max_memory_mb=BUDGET, **kw)
    print(f"budget plan: {plan.as_dict()}", file=sys.stderr, flush=True)
    return res


reconstruction_node.reconstruct_aligned = _within_budget

if __name__ == "__main__":
    raise SystemExit(pipeline.main())
