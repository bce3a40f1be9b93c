"""
csb's OpenGL viewer: a window, or offscreen rendering into images and MP4
"""
from __future__ import annotations
import collections.abc
import csb._core
import numpy
import numpy.typing
import typing
__all__: list[str] = ['Camera', 'Viewer', 'command']
class Camera:
    """
    The viewer's orbit camera (m, rad; pixels from the top-left corner).
    """
    def orbit(self, dx: typing.SupportsFloat | typing.SupportsIndex, dy: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    def pan(self, dx: typing.SupportsFloat | typing.SupportsIndex, dy: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    def project(self, point: typing.Any) -> tuple[float, float, float]:
        """
        (x, y, depth): where a world point (m) lands in the image, in pixels, and its depth (m) in front of the eye
        """
    def ray(self, x: typing.SupportsFloat | typing.SupportsIndex, y: typing.SupportsFloat | typing.SupportsIndex) -> tuple[typing.Annotated[numpy.typing.NDArray[numpy.float64], "[3, 1]"], typing.Annotated[numpy.typing.NDArray[numpy.float64], "[3, 1]"]]:
        """
        (origin, unit direction) of the ray through pixel (x, y)
        """
    def zoom(self, steps: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def distance(self) -> float:
        """
        m, from the eye to the target
        """
    @distance.setter
    def distance(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def eye(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[3, 1]"]:
        ...
    @property
    def forward(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[3, 1]"]:
        ...
    @property
    def fov_y(self) -> float:
        """
        rad, vertical field of view
        """
    @fov_y.setter
    def fov_y(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def height(self) -> int:
        ...
    @property
    def pitch(self) -> float:
        """
        rad above the horizon
        """
    @pitch.setter
    def pitch(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    @property
    def target(self) -> typing.Annotated[numpy.typing.NDArray[numpy.float64], "[3, 1]"]:
        """
        m, the point looked at
        """
    @target.setter
    def target(self, arg1: typing.Any) -> None:
        ...
    @property
    def width(self) -> int:
        ...
    @property
    def yaw(self) -> float:
        """
        rad about +y; 0 looks along -z
        """
    @yaw.setter
    def yaw(self, arg0: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
class Viewer:
    """
    Steps a simulation in real time and draws it with OpenGL 3.3, in a window or offscreen. See csb.view().
    """
    grid: bool
    particles: bool
    paused: bool
    wireframe: bool
    def __enter__(self) -> Viewer:
        ...
    def __exit__(self, *args) -> None:
        ...
    @typing.overload
    def __init__(self, model: csb._core.Model, state: csb._core.State, stepper: csb._core.Integrator, *, width: int = 1280, height: int = 800, offscreen: bool = False, title: str = 'csb', samples: int = 4, vsync: bool = True, overlay: bool = True, wireframe: bool = False, particles: bool = False, grid: bool = True, paused: bool = False, frame_time: typing.SupportsFloat | typing.SupportsIndex = 0.016666666666666666, grab_compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, tear_max_strain: typing.SupportsFloat | typing.SupportsIndex = 0.0, tear_max_per_step: int = 1, screenshot_prefix: str = 'csb-screenshot', gravity: typing.Any = None, substeps: typing.Any = None, iterations: typing.Any = None) -> None:
        """
        Copies model and state (reset returns to them) and steps them with `stepper`, any csb.Integrator (a built-in, or a Python subclass: kept alive by the viewer). Grabbing needs a PbdStepper. The method switch (the `method` property, the m and 1-9 keys) goes through csb.methods(): it works for a PbdStepper (made from its settings), and for a built-in stepper given `substeps` and `iterations`, the settings (with its dt() and `gravity`) the other methods are made with; without them, for a user's own method, it is off. width, height: pixels. offscreen: EGL, no window. frame_time: s of simulated time per frame (whole steps of the stepper's dt()). grab_compliance: m/N of the mouse's grab (0: kinematic). tear_max_strain: tearing after every step (0: none). gravity: m/s², for the overlay's energies when the stepper is not a PbdStepper (default (0, -9.81, 0)). csb.SimulationError (a diverging method) or csb.ParameterError (a model the method refuses) from a built-in pauses the viewer and is shown; any other exception the stepper raises passes through frame(), run() and capture().
        """
    @typing.overload
    def __init__(self, model: csb._core.Model, state: csb._core.State, settings: csb._core.PbdSettings, *, width: int = 1280, height: int = 800, offscreen: bool = False, title: str = 'csb', samples: int = 4, vsync: bool = True, overlay: bool = True, wireframe: bool = False, particles: bool = False, grid: bool = True, paused: bool = False, frame_time: typing.SupportsFloat | typing.SupportsIndex = 0.016666666666666666, grab_compliance: typing.SupportsFloat | typing.SupportsIndex = 0.0, tear_max_strain: typing.SupportsFloat | typing.SupportsIndex = 0.0, tear_max_per_step: int = 1, screenshot_prefix: str = 'csb-screenshot') -> None:
        """
        The same with a PbdStepper made from `settings`.
        """
    def capture(self, *, frames: int, directory: str, every: int = 1, prefix: str = 'frame', png: bool = True, video: bool = True, progress: typing.Any = None) -> dict:
        """
        Draws `frames` frames and writes every `every`-th as <directory>/<prefix>_NNNNN.png, and <prefix>.mp4 when ffmpeg is on the PATH. Returns the files and the median ms per frame. progress(frames_done), if given, is called after each frame.
        """
    def close(self) -> None:
        """
        Releases the window (or offscreen context) now; frame() then returns False.
        """
    def collider_poses(self) -> list:
        """
        (rotation, translation in m) of every collider as frames draw it now: the stepper's pose at the end of its last step (PbdStepper.collider_pose), the identity (as declared) for a method that does not move colliders.
        """
    def collider_vertices(self) -> list:
        """
        Per collider, the vertices (V x 3, m, model frame; collider_poses() applies on top) frames draw a deforming mesh collider with now (PbdStepper.collider_vertices), None for a collider that does not deform (drawn as declared).
        """
    def frame(self) -> bool:
        """
        One frame: events, the simulation's advance (unless paused), drawing. False once the window closed.
        """
    def frame_scene(self) -> None:
        ...
    def key(self, name: str) -> None:
        """
        A synthetic key press by name: 'space', 'period', 'right', 'escape', or a letter or digit.
        """
    def mouse_button(self, button: int, pressed: bool, x: typing.SupportsFloat | typing.SupportsIndex, y: typing.SupportsFloat | typing.SupportsIndex, shift: bool = False) -> None:
        """
        A synthetic mouse button event: button 0 left, 1 right, 2 middle; x, y in pixels.
        """
    def mouse_move(self, x: typing.SupportsFloat | typing.SupportsIndex, y: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    def redraw(self) -> None:
        """
        Draws the current state again without stepping.
        """
    def reset(self) -> None:
        ...
    def run(self, max_frames: int = 0) -> int:
        """
        Frames until the window closes (or max_frames > 0 were drawn); returns the frames drawn. The GIL is released during each frame; Python's signals (Ctrl-C: KeyboardInterrupt) are handled between frames.
        """
    def save_png(self, path: str) -> None:
        ...
    def screenshot(self) -> numpy.typing.NDArray[numpy.uint8]:
        """
        The last frame drawn as an (height, width, 3) uint8 array, top row first.
        """
    def scroll(self, steps: typing.SupportsFloat | typing.SupportsIndex) -> None:
        ...
    def set_before_step(self, before_step: collections.abc.Callable[[csb._core.Integrator, csb._core.Model, csb._core.State, bool], None] | None) -> None:
        """
        before_step(stepper, model, state, fresh), called before every step (None: nothing): where a scene moves its colliders (stepper.move_collider to their poses at the step's end, state.t + dt) and attaches particles to them when `fresh` (the first step of the first stepper, or of one a reset or the method switch made). An exception it raises passes through frame(), run() and capture().
        """
    def set_overlay(self, on: bool) -> None:
        ...
    def single_step(self) -> None:
        ...
    @property
    def camera(self) -> Camera:
        ...
    @property
    def closed(self) -> bool:
        """
        The window was asked to close, or close() was called.
        """
    @property
    def dt(self) -> float:
        """
        s, the method's step
        """
    @property
    def held_particle(self) -> int:
        """
        The particle under the mouse's grab, or -1.
        """
    @property
    def message(self) -> str:
        """
        The overlay's last notice: a method switch (with what the method cannot read of the model's material), a method that cannot step the model, a screenshot written, a simulation error.
        """
    @property
    def method(self) -> str:
        """
        The method's name (csb.methods()' name, or a user's method's name()). Set: any registered method or alias ('pbd', 'xpbd', 'small-steps', 'symplectic-euler', 'backward-euler', ... see csb.methods()), from the same state; csb.ParameterError saying why, with the method and the state unchanged, when the method cannot step this model (hard constraints, colliders, ...) or the switch is off (a user's own method).
        """
    @method.setter
    def method(self, arg1: str) -> None:
        ...
    @property
    def method_switch(self) -> bool:
        """
        Whether the method switch works: the viewer knows the settings to make the methods from (a PbdStepper's, or the substeps and iterations given with a built-in).
        """
    @property
    def model(self) -> csb._core.Model:
        """
        A copy of the model being simulated (a tear makes a new one).
        """
    @property
    def position_based(self) -> bool:
        """
        Whether the method is a PbdStepper: grabbing works only then.
        """
    @property
    def settings(self) -> typing.Any:
        """
        The PbdStepper's settings, or None for another method.
        """
    @property
    def state(self) -> csb._core.State:
        """
        The live state (positions and velocities as numpy views).
        """
    @property
    def stats(self) -> dict:
        """
        What the overlay shows: fps, ms per frame, per step and to draw (wall clock, smoothed), energies (J).
        """
    @property
    def stepper(self) -> csb._core.Integrator:
        """
        The Integrator being stepped (after a method switch or a reset of a PbdStepper, a new one).
        """
    @property
    def steps_per_frame(self) -> int:
        ...
def command(args: collections.abc.Sequence[str]) -> int:
    """
    Runs the csb-view command on args (without the program's name); returns its exit status.
    """
