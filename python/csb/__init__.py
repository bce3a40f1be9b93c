"""csb — cloth and soft-body dynamics with Position Based Dynamics, and a testbed that holds every
method against a trusted reference.

Quick start::

    import csb
    mesh = csb.load_mesh("cloth.obj")                 # any format Assimp reads
    b = csb.ModelBuilder()
    cloth = b.add_mesh(mesh, mass=0.2, stretch_stiffness=1.0, bending_stiffness=0.1)
    b.pin(cloth.nearest([-0.5, 0, -0.5]))
    model = b.build()
    state = model.initial_state()
    pbd = csb.PbdStepper(dt=1 / 60, substeps=2, iterations=10)
    pbd.step(model, state, steps=60)
    state.x                                           # (N, 3) positions, a zero-copy view

Units are SI throughout: m, kg, s, rad; time step (dt), substeps and iterations are separate.
"""

from __future__ import annotations

from . import _core  # noqa: F401  (csb._core, the compiled module)
from ._core import (
    AccuracyWarning,
    ConcurrentUseError,
    Error,
    ForceStepper,
    Integrator,
    MaterialWarning,
    BackwardEuler,
    BackwardEulerResidual,
    VertexBlockDescent,
    ProjectiveDynamics,
    IncrementalPotential,
    MeshError,
    Model,
    ParameterError,
    PbdSettings,
    PbdStepper,
    Pick,
    Plugin,
    PluginIntegrator,
    SimulationError,
    State,
    backward_euler_residual,
    balloon_volumes,
    bending_violations,
    build_info,
    chain,
    cloth_grid,
    corrected_stiffness,
    distance_violations,
    elastic_energy,
    kernels,
    load_plugin,
    lumped_measure,
    make_integrator,
    method_info,
    measure,
    methods,
    pendulum,
    pick_particle,
    tear,
    readable_extensions,
    save_mesh,
    topology,
    volume_violations,
)
from .mesh import AnimationWarning, Mesh, MeshReport, MeshWarning, SourceMesh, clean, icosphere, load_mesh, transformed
from .animation import AnimatedMesh, Animation, RigidKeyframes, load_animation
from .model import MeshInstance, ModelBuilder
from .select import Box, HalfSpace, Material, NearLine, Region, Sphere
from .family import ConstraintFamily, ShapeMatching
from .tetmesh import TetMesh, load_tet_mesh, tet_box
from .reference import ReferenceResult, SpringNetwork, integrate_reference, position_error
from .runner import RunResult
from .scene import Scene, SceneError, Simulation, bundled_scenes, find_scene, load_scene
from .view import CameraPose, RenderResult, open_viewer, render, view, viewer_available, viewer_missing

__version__ = build_info()["csb"]


def plugin_include_dir() -> str:
    """The folder holding csb_plugin.h, the C interface of a method brought as a plug-in
    (csb.load_plugin), as installed with this package: compile a plug-in with ``-I`` this folder,
    e.g. ``cmake -DCSB_PLUGIN_INCLUDE_DIR=$(python -c 'import csb; print(csb.plugin_include_dir())')``."""
    from pathlib import Path

    folder = Path(__file__).resolve().parent / "include"
    if not (folder / "csb_plugin.h").is_file():
        raise FileNotFoundError(f"csb_plugin.h is not installed in {folder}: reinstall csb")
    return str(folder)


__all__ = [
    "Error", "ParameterError", "MeshError", "SimulationError", "ConcurrentUseError", "SceneError", "MeshWarning", "AnimationWarning", "MaterialWarning", "AccuracyWarning",
    "Mesh", "MeshReport", "SourceMesh", "load_mesh", "load_animation", "Animation", "AnimatedMesh", "RigidKeyframes", "save_mesh", "clean", "transformed", "topology", "lumped_measure",
    "readable_extensions", "cloth_grid", "chain", "pendulum", "icosphere",
    "TetMesh", "load_tet_mesh", "tet_box", "volume_violations", "balloon_volumes",
    "Model", "ModelBuilder", "MeshInstance", "State", "Region", "Box", "Sphere", "HalfSpace", "NearLine", "Material", "ConstraintFamily", "ShapeMatching",
    "Integrator", "methods", "method_info", "make_integrator", "load_plugin", "Plugin", "PluginIntegrator", "plugin_include_dir", "PbdStepper", "PbdSettings", "ForceStepper", "corrected_stiffness", "pick_particle", "Pick", "tear",
    "measure", "elastic_energy", "distance_violations", "bending_violations", "kernels",
    "integrate_reference", "ReferenceResult", "SpringNetwork", "position_error",
    "BackwardEuler", "IncrementalPotential", "backward_euler_residual", "BackwardEulerResidual",
    "VertexBlockDescent", "ProjectiveDynamics",
    "Scene", "Simulation", "RunResult", "load_scene", "bundled_scenes", "find_scene",
    "view", "render", "open_viewer", "viewer_available", "viewer_missing", "CameraPose", "RenderResult",
    "build_info", "__version__",
]
