"""Declarative studies: a TOML file of scenes, methods with their parameter grids, a reference,
metrics and repeats, expanded into cells (the Cartesian product), each cell run by one pure
function of its definition and stored under a key made from everything that determines it.

A study file::

    [study]
    name = "pareto"                  # the output folder's name (default: the file's stem)
    description = "..."
    tier = "quick"                   # "quick": in the main job's default run; "full" (default): with --full
    duration = 0.3                   # s of simulated time per cell
    outputs = 10                     # output intervals: metrics are measured at these 11 times
    repeats = "auto"                 # timed runs per cell (an integer), or as many as the spread asks
    budget = 6                       # optional: every method must have this many settings per scene
    metrics = ["position_error", "energy_drift", "max_strain", "max_violation", "residual",
               "same_step_error", "volume_error", "stability"]
    profile_accuracy = 5e-3          # optional (m): the report's performance profile at this accuracy

    [reference]                      # the continuous CVODE reference (csb.integrate_reference)
    rtol = "auto"                    # or a tolerance (atol default rtol/100); "auto" tightens it until
    fraction = 0.01                  # its own error is this fraction of the smallest a cell shows

    [[scene]]                        # one of: scene = a bundled scene's name, file = a scene file,
    setup = "swinging_chain"         # setup = a study set-up (SETUPS, the literature's among them)
    args = { links = 5 }
    grid = { compliance = [1e-6, 1e-4] }   # a set-up's arguments swept: one scene per value
    metrics = ["residual", "stability"]    # optional: the study's metrics measured on this scene
                                           # (without position_error, no reference is run for it)

    [[method]]
    name = "xpbd"                    # a built-in (csb.methods()) or "cvode"; or python = "module:Class"
    dt = [0.0333, 0.00833]           # for a user's csb.Integrator (args = { ... } its keyword
    iterations = [1, 20]             # arguments), or plugin = "libmine.so" (csb.load_plugin);
                                     # grids: dt (s), substeps, iterations; rtol for "cvode"

    [[chart]]                        # besides the accuracy-against-cost chart (with position_error):
    kind = "map"                     # "line": y (a metric) against x (a parameter, or the cost
                                     # cpu_per_simulated_s with along = the parameter joined), or "map": the
    x = "dt"                         # stability class over x and y (parameters or scene grid
    y = "compliance"                 # arguments), "stable but wrong" beyond wrong (m) from the
    wrong = 0.05                     # reference; optional: scenes = [...], methods = [...] it draws

Every error names the study file, the line and the key (:class:`StudyError`). The cells' results
are files ``<out>/cells/<key>.json`` (with their positions at the output times, ``<key>.npy``),
written atomically, so a run killed at any point keeps every
cell it finished, and a re-run computes only the missing ones. Cells run on Dask (a
``distributed.LocalCluster`` by default, or a scheduler by address) or, with ``workers=0``, in
this process; either way through :func:`run_cell`.
"""

from .cells import run_cell
from .execute import StudyResult, run_study
from .schema import METRICS, SETUPS, Cell, Study, StudyError, cell_key, load_study

__all__ = ["StudyError", "Study", "Cell", "StudyResult", "load_study", "run_study", "run_cell", "cell_key",
           "METRICS", "SETUPS"]
