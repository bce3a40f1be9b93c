"""Declarative studies: a TOML file of scenes, methods with their parameter grids, a reference,
metrics and repeats, expanded into cells (the Cartesian product), each cell run by one pure
function of its definition and stored under a key made from everything that determines it.

A study file::

    [study]
    name = "pareto"                  # the output folder's name (default: the file's stem)
    description = "..."
    duration = 0.3                   # s of simulated time per cell
    outputs = 10                     # output intervals: metrics are measured at these 11 times
    repeats = 2                      # timed runs per cell: the cost is their median and spread
    metrics = ["position_error", "energy_drift", "max_strain", "max_violation", "stability"]

    [reference]                      # the continuous CVODE reference (csb.integrate_reference)
    rtol = 1e-11                     # or "auto" (with energy_tolerance); atol default rtol/100

    [[scene]]                        # one of: scene = a bundled scene's name, file = a scene file,
    setup = "swinging_chain"         # setup = a study set-up (SETUPS) with its args
    args = { links = 5 }
    grid = { compliance = [1e-6, 1e-4] }   # a set-up's arguments swept: one scene per value

    [[method]]
    name = "xpbd"                    # a built-in (csb.methods()) or "cvode"; or
    dt = [0.0333, 0.00833]           # python = "module:Class" for a user's csb.Integrator
    iterations = [1, 20]             # grids: dt (s), substeps, iterations; rtol for "cvode"

Every error names the study file, the line and the key (:class:`StudyError`). The cells' results
are files ``<out>/cells/<key>.json``, written atomically, so a run killed at any point keeps every
cell it finished, and a re-run computes only the missing ones. Cells run on Dask (a
``distributed.LocalCluster`` by default, or a scheduler by address) or, with ``workers=0``, in
this process; either way through :func:`run_cell`.
"""

from .cells import run_cell
from .execute import StudyResult, run_study
from .schema import METRICS, SETUPS, Cell, Study, StudyError, cell_key, load_study

__all__ = ["StudyError", "Study", "Cell", "StudyResult", "load_study", "run_study", "run_cell", "cell_key",
           "METRICS", "SETUPS"]
