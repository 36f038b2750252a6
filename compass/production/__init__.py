"""Production: acceptance specs, the calibration store, the fleet report (issue 26).

The batch itself (calibrating many recordings on a process pool or a Dask cluster) is
:mod:`calibrate.batch`; this package is what it judges by and writes into, and what the runtime
side reads back (``compass store``, ``compass export --module``).
"""

from .control import EwmaChart, ewma_chart
from .figures import FIGURES, WARNING_CLASSES, classify_warning, module_figures
from .spec import DEFAULT_SPEC, AcceptanceSpec, SpecError, Verdict, load_spec, parse_spec
from .store import SCHEMA_VERSION, SessionRow, Store, StoreError

__all__ = ["DEFAULT_SPEC", "FIGURES", "SCHEMA_VERSION", "WARNING_CLASSES", "AcceptanceSpec", "EwmaChart",
           "SessionRow", "SpecError", "Store", "StoreError", "Verdict", "classify_warning", "ewma_chart",
           "load_spec", "module_figures", "parse_spec"]
