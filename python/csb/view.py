"""The real-time viewer from Python: :func:`view` opens a window on a scene, :func:`render` draws
frames of it offscreen into PNG files (and an MP4 when ffmpeg is installed).

The viewer is C++ (GLFW, OpenGL 3.3 core, GLSL; ``src/viewer/``) in a module of its own,
``csb._viewer``, apart from the simulation in ``csb._core``: csb imports and simulates without
it. It is optional in the build, and a wheel carries it but not the system's OpenGL and X11
libraries. When it was not built or cannot load, :func:`viewer_available` is False and every
function here raises :class:`csb.Error` saying what is missing.

In the window: the left button on the mesh grabs the particle under the cursor and drags it in
the plane facing the camera; elsewhere it orbits. Right or middle button (or shift + left) pans,
the wheel zooms. Keys: space pause, ``.`` one step, ``r`` reset, ``w`` wireframe, ``p``
particles, ``m`` next method, ``1`` to ``9`` a method, ``o`` overlay, ``g`` grid, ``f`` frame
the scene, ``c`` screenshot, ``q`` quit.

The method keys go through every built-in method, :func:`csb.methods` in its order (the overlay
lists them): the position-based variants are made from the scene's solver settings (switching
back restores them), the others with :func:`csb.make_integrator` from its dt, substeps,
iterations and gravity. The switch keeps the state. A method that cannot step the model (one
that models constraints as springs refuses those of compliance 0; some refuse colliders) is not
switched to: the overlay says why, the method stays and ``m`` goes on past it; a method that
diverges pauses the viewer with its error. Grabbing with the mouse works with the
position-based methods only.

Moving colliders move in the viewer and in :func:`render` as in ``csb run``: before every step
each collider with a motion (its keyframes, or ``Simulation.collider_motion``) goes to its pose at
the step's end, the scene's particles attached to a collider are attached to each stepper the
viewer makes (the first, and on a reset or a method switch), and every frame draws each collider
at the pose the stepper reports (``PbdStepper.collider_pose``, ``Viewer.collider_poses()``). A
mesh collider that deforms (a skinned file's animation, ``animation = true``, or
``Simulation.collider_deformation``) gets its vertices at the step's end before every step the
same way, and is drawn in the shape the stepper reports (``PbdStepper.collider_vertices``,
``Viewer.collider_vertices()``); a static mesh is uploaded once. A
method that is not position-based does not move colliders: they stay, and are drawn, as
declared. The stepper a method switch makes has the colliders at their declared poses: part-way
through a moving scene they go back to their motion within its first step, and particles
attached to them jump by the collider's displacement (0.4 m in cape_wave after 1 s); switch
methods after a reset (``r``). The camera frames the scene as declared.
"""

from __future__ import annotations

import functools
import importlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Union

from . import _core
from .scene import Scene, Simulation, load_scene

SceneLike = Union[str, "os.PathLike[str]", Scene, Simulation, _core.Model]


@functools.cache
def _viewer_or_why() -> tuple[ModuleType | None, str]:
    status = _core.build_info().get("viewer", "not built")
    if status != "built":
        return None, ("the viewer is not part of this build of csb: missing " + status.removeprefix("not built: ")
                      + ". On Debian/Ubuntu: apt-get install libglfw3-dev libepoxy-dev libegl-dev libimgui-dev "
                      "libpng-dev, then rebuild (./dev setup)")
    try:
        return importlib.import_module("csb._viewer"), ""
    except ImportError as e:  # a wheel's viewer on a machine without the display libraries it uses
        return None, (f"the viewer cannot load: {e}. It needs the system's X11, OpenGL and EGL libraries (on "
                      "Debian/Ubuntu: apt-get install libx11-6 libgl1 libegl1 libegl-mesa0 libgl1-mesa-dri); the rest "
                      "of csb works without them")


def viewer_available() -> bool:
    """Whether the viewer was built and loads on this machine."""
    return _viewer_or_why()[0] is not None


def viewer_missing() -> str:
    """Why the viewer is not available ('' when it is)."""
    return _viewer_or_why()[1]


def viewer_module() -> ModuleType:
    """The compiled viewer, ``csb._viewer`` (its ``Viewer`` and ``Camera``); :class:`csb.Error` saying
    what is missing when it is not available."""
    module, why = _viewer_or_why()
    if module is None:
        raise _core.Error(why)
    return module


def _simulation(scene: SceneLike) -> Simulation:
    if isinstance(scene, Simulation):
        return scene
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    return scene.build()


@dataclass(frozen=True)
class CameraPose:
    """Where the camera looks from (rad, and a factor on the distance that frames the scene)."""

    yaw: float | None = None         # rad about +y, 0 looks along -z
    pitch: float | None = None       # rad above the horizon
    zoom: float = 1.0                # < 1 closer, > 1 farther than the framing distance


def open_viewer(scene: SceneLike, *, offscreen: bool = False, width: int = 1280, height: int = 800,
                method: str | None = None, camera: CameraPose | None = None,
                stepper: "_core.Integrator | None" = None, state: "_core.State | None" = None,
                **options: Any) -> "csb._viewer.Viewer":
    """A viewer on a scene (a bundled scene's name, a scene file, a Scene or a built Simulation)
    or on a Model built in Python, from `state` (default its initial state) with `stepper` (any
    csb.Integrator; default a PbdStepper of default settings), not yet running: call ``run()``
    for the window's loop, ``frame()`` for one frame. The viewer steps a copy of the state. `method`,
    any built-in method's name or alias (:func:`csb.methods`: 'pbd', 'xpbd', 'jakobsen'/'verlet',
    'symplectic-euler', 'backward-euler', ...), replaces the scene's, made from the scene's solver
    settings as the method keys make it: a method that cannot step the scene's model (a spring
    model given constraints of compliance 0, say) is a :class:`csb.ParameterError` saying why. `stepper`, any csb.Integrator (a built-in or a user's own method), steps the scene
    instead of its solver: the method keys then work from a built-in's settings (its dt, and its
    substeps or the solver's) and are off for a user's own; grabbing works with a PbdStepper only.
    `options` go to :class:`csb._viewer.Viewer` (overlay, wireframe, particles, paused, frame_time,
    grab_compliance, samples, vsync, title, ...). A scene with tearing tears in the viewer too."""
    Viewer = viewer_module().Viewer  # csb.Error saying what is missing, before any work
    if stepper is not None and not isinstance(stepper, _core.Integrator):
        raise _core.ParameterError(f"stepper must be a csb.Integrator, got {type(stepper).__name__}")
    if isinstance(scene, _core.Model):
        v = _model_viewer(scene, state, stepper, width=width, height=height, offscreen=offscreen, **options)
        return _finish(v, method, camera)
    if state is not None:
        raise _core.ParameterError("state goes with a Model; a scene starts from its own")
    sim = _simulation(scene)
    tearing = sim.scene.tearing
    if tearing is not None:
        options.setdefault("tear_max_strain", tearing.max_strain)
        options.setdefault("tear_max_per_step", tearing.max_per_step)
    options.setdefault("title", f"csb - {sim.scene.name}")
    if stepper is None and isinstance(sim.stepper, _core.PbdStepper):  # a fresh one, of the scene's settings
        v = Viewer(sim.model, sim.state, sim.stepper.settings, width=width, height=height, offscreen=offscreen,
                   **options)
    else:
        given = stepper if stepper is not None else sim.stepper
        registered = {name for m in _core.methods() for name in (m.name, *m.aliases)}
        if type(given).__module__ == _core.__name__ and given.name() in registered:
            # A built-in method (a user's subclass is defined elsewhere, a plug-in is not in the
            # registry): the method keys make the other methods with its substeps where it has
            # them, else the solver's, and the solver's iterations.
            solver = sim.scene.solver
            own = getattr(given, "settings", None)
            options.setdefault("substeps", getattr(own, "substeps", solver.substeps))
            options.setdefault("iterations", getattr(own, "iterations", solver.iterations))
        v = Viewer(sim.model, sim.state, given, width=width, height=height, offscreen=offscreen,
                   gravity=sim.gravity, **options)
    before_step = _scene_motion(sim)
    if before_step is not None:
        v.set_before_step(before_step)
    return _finish(v, method, camera)


def _model_viewer(model: _core.Model, state: "_core.State | None", stepper: "_core.Integrator | None",
                  **options: Any) -> "csb._viewer.Viewer":
    """A viewer on a Model and State: the stepper's settings for a PbdStepper (grabbing on), else
    the Integrator itself; gravity the PbdStepper's, else (0, -9.81, 0) m/s²."""
    if state is None:
        state = model.initial_state()
    elif not isinstance(state, _core.State):
        raise _core.ParameterError(f"state must be a csb.State, got {type(state).__name__}")
    elif state.x.shape[0] != model.num_particles:
        raise _core.ParameterError(f"state has {state.x.shape[0]} particles, the model {model.num_particles}")
    options.setdefault("title", "csb - model")
    if stepper is None or isinstance(stepper, _core.PbdStepper):
        settings = (stepper or _core.PbdStepper()).settings
        return viewer_module().Viewer(model, state, settings, **options)
    gravity = options.pop("gravity", (0.0, -9.81, 0.0))
    return viewer_module().Viewer(model, state, stepper, gravity=gravity, **options)


def _finish(v: "csb._viewer.Viewer", method: str | None, camera: CameraPose | None) -> "csb._viewer.Viewer":
    if method is not None:
        try:
            v.method = method
        except BaseException:
            v.close()
            raise
    if camera is not None:
        if camera.yaw is not None:
            v.camera.yaw = camera.yaw
        if camera.pitch is not None:
            v.camera.pitch = camera.pitch
        if camera.zoom <= 0:
            raise _core.ParameterError(f"camera zoom must be > 0, got {camera.zoom}")
        v.camera.distance *= camera.zoom
    return v


def _scene_motion(sim: Simulation) -> Callable[..., None] | None:
    """What the viewer calls before each step for a scene whose colliders move (keyframes,
    ``Simulation.collider_motion``), deform, or carry attached particles: as
    :meth:`Simulation.step` does, every moving collider goes to its pose at the step's end
    (t + dt) and every deforming one to its vertices then, and a stepper the viewer has just made
    (the first, or one of a reset or a method switch) gets the scene's attachments.
    The renderer then draws each collider at the stepper's pose (``Viewer.collider_poses()``). A
    method that is not position-based does not move colliders: they stay, and are drawn, as
    declared. None for a scene with neither."""
    motions = sim._motions()
    # Mesh colliders that deform (a skinned file's animation, Simulation.collider_deformation):
    # (index, f(t) -> (V, 3) vertices in m), given to PbdStepper.deform_collider as step() does;
    # frames then draw them in that shape (Viewer.collider_vertices()).
    deformations = sim._deformations()
    attached: dict[int, list[int]] = {}
    if isinstance(sim.stepper, _core.PbdStepper):
        for a in sim.stepper.attachments:
            attached.setdefault(a["collider"], []).append(a["particle"])
    if not motions and not deformations and not attached:
        return None
    names = {i: n for n, i in sim.colliders.items()}

    def before_step(stepper: _core.Integrator, model: _core.Model, state: _core.State, fresh: bool) -> None:
        if not isinstance(stepper, _core.PbdStepper):
            return
        if fresh:
            for collider, particles in attached.items():
                stepper.attach(model, state, collider, particles)
        t = state.t + stepper.dt()  # s, the step's end
        for index, pose in motions:
            try:
                R, tr = pose(t)
                stepper.move_collider(model, index, R, tr)
            except _core.ParameterError as e:
                raise _core.ParameterError(f"collider '{names[index]}' at t = {t:.6g} s: {e}") from None
        for index, vertices in deformations:
            try:
                stepper.deform_collider(model, index, vertices(t))
            except _core.ParameterError as e:
                raise _core.ParameterError(f"collider '{names[index]}' at t = {t:.6g} s: {e}") from None

    return before_step


def view(scene: SceneLike, *, frames: int = 0, **options: Any) -> int:
    """Opens a window on a scene and runs it in real time until the window is closed (or
    `frames` > 0 frames were drawn); returns the frames drawn. Needs a display (X11 or
    Wayland/XWayland); without one use :func:`render`. Options as for :func:`open_viewer`."""
    with open_viewer(scene, **options) as v:
        return v.run(frames)


@dataclass
class RenderResult:
    """What :func:`render` wrote. In a Jupyter notebook it shows itself: the MP4 as a video when
    there is one, else the last frame."""

    images: list[Path] = field(default_factory=list)
    video: Path | None = None
    video_note: str = ""
    ms_per_frame: float = 0.0        # median wall time per frame: step, draw and read-back
    draw_ms_per_frame: float = 0.0   # median wall time to draw and read back a frame
    size: tuple[int, int] = (0, 0)   # width, height in pixels

    def _repr_html_(self) -> str:
        import base64

        w, h = self.size
        if self.video is not None and self.video.exists():
            data = base64.b64encode(self.video.read_bytes()).decode()
            return (f'<video width="{w}" height="{h}" controls loop autoplay muted>'
                    f'<source src="data:video/mp4;base64,{data}" type="video/mp4"></video>')
        if self.images:
            data = base64.b64encode(self.images[-1].read_bytes()).decode()
            return f'<img width="{w}" height="{h}" src="data:image/png;base64,{data}"/>'
        return "<p>no frame written</p>"


def render(scene: SceneLike, out: str | os.PathLike[str], *, frames: int = 60, every: int = 1,
           width: int = 960, height: int = 600, video: bool = True, prefix: str = "frame",
           overlay: bool = False, progress: bool = False, **options: Any) -> RenderResult:
    """Draws `frames` frames of a scene (or of a Model and its ``state=``, stepped by ``stepper=``,
    any csb.Integrator: see :func:`open_viewer`) offscreen (EGL: no window, no display needed), each
    advancing the simulation by frame_time (default 1/60 s), and writes every `every`-th (and the
    last) as ``<out>/<prefix>_NNNNN.png``, and all of them as ``<out>/<prefix>.mp4`` (in real
    time) when ffmpeg is on the PATH and `video` is set. `progress`: a progress bar on stderr."""
    if frames < 1:
        raise _core.ParameterError(f"frames must be >= 1, got {frames}")
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=frames, unit="frame", desc="render", leave=False, dynamic_ncols=True)
    try:
        with open_viewer(scene, offscreen=True, width=width, height=height, overlay=overlay, **options) as v:
            r = v.capture(frames=frames, directory=os.fspath(out), every=every, prefix=prefix, video=video,
                          progress=(lambda done: bar.update(done - bar.n)) if bar is not None else None)
    finally:
        if bar is not None:
            bar.close()
    return RenderResult(images=[Path(p) for p in r["images"]], video=Path(r["video"]) if r["video"] else None,
                        video_note=r["video_note"], ms_per_frame=r["ms_per_frame"],
                        draw_ms_per_frame=r["draw_ms_per_frame"], size=(width, height))
