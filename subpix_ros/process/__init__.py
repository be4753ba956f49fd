"""Post-flight processing (``subpix process``, ``subpix report``), without DDS.

Flight bags go through the ROS-free stage pipeline into products and a flight report:
:mod:`.inputs` opens a flight, :mod:`.flight` processes one bag, :mod:`.batch` many,
:mod:`.products` writes the products and :mod:`.report` the report. The public names are
exported here lazily, so ``subpix report`` does not load the stages.
"""

from __future__ import annotations

from subpix_ros._lazy import lazy_exports

_EXPORTS = {
    "InputError": "inputs",
    "Flight": "inputs",
    "open_flight": "inputs",
    "bag_name": "inputs",
    "BagResult": "flight",
    "process_bag": "flight",
    "Progress": "batch",
    "run_batch": "batch",
    "interrupt_on_signals": "batch",
    "load_params": "params",
    "load_params_files": "params",
    "ParamsError": "params",
    "check_params": "params",
    "pipeline_params": "params",
    "ProductWriter": "products",
    "is_complete": "products",
    "read_csv": "products",
    "build_report": "report",
    "write_report": "report",
}

__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
