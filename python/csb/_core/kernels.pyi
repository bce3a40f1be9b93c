"""
The constraint kernels on single constraints (for tests and teaching).
"""
from __future__ import annotations
import collections.abc
import numpy
import numpy.typing
import typing
__all__: list[str] = ['additive_ccd', 'atan2', 'dihedral_angle', 'dihedral_angle_gradient', 'enclosed_volume', 'kernel_isa', 'project_attachment', 'project_attachment_xpbd', 'project_balloon', 'project_bending', 'project_bending_coloured', 'project_bending_xpbd', 'project_distance', 'project_distance_jakobsen', 'project_distance_xpbd', 'project_volume', 'project_volume_xpbd', 'tet_volume', 'tet_volume_gradient']
def additive_ccd(kind: str, x: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[4, 3]"], dx: typing.Annotated[numpy.typing.ArrayLike, numpy.float64, "[4, 3]"], separation: typing.SupportsFloat | typing.SupportsIndex = 0.1, thickness: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> tuple[bool, float]:
    """
    Additive CCD (Li, Kaufman, Jiang 2021) of a pair moving from x to x + dx ((4, 3), m; point-triangle: the point then the triangle, edge-edge: the two edges' ends): (hit, toi), the first fraction of the motion at which the distance falls below thickness + separation (d(0) - thickness), conservatively.
    """
def atan2(y: typing.Any, x: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
    """
    The coloured bending kernel's branch-free rational atan2 (csb/atan2.hpp), elementwise, rad.
    """
def dihedral_angle(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any) -> float:
    """
    Signed dihedral angle across edge (a, b), rad.
    """
def dihedral_angle_gradient(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any) -> typing.Any:
    """
    (4, 3) gradient, rad/m; None if degenerate.
    """
def enclosed_volume(points: typing.Any, triangles: typing.Any) -> float:
    """
    (1/6) Σ (p_a x p_b)·p_c over the triangles, m³.
    """
def kernel_isa(isa: str | None = None) -> str:
    """
    The instruction set of the blocked coloured kernels (bending; PBD distance): 'avx512', 'avx2' or 'sse2' (x86-64 portable build, the best the processor has; 'avx512' runs bending in AVX-512 and distance in AVX2), 'native' (a CSB_NATIVE build, or not x86-64). isa='sse2', 'avx2' or 'avx512' forces that copy (an error if the processor lacks it), 'auto' the processor's choice; returns the one in use.
    """
def project_attachment(p: typing.Any, w: typing.SupportsFloat | typing.SupportsIndex, target: typing.Any, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[numpy.ndarray, float]:
    """
    PBD's attachment (a particle held at a world point): C = |p - target|, Δp = -k C n for a particle that can move (w > 0). Returns (p', violation before, m).
    """
def project_attachment_xpbd(p: typing.Any, w: typing.SupportsFloat | typing.SupportsIndex, target: typing.Any, alpha_tilde: typing.SupportsFloat | typing.SupportsIndex, lambda_: typing.SupportsFloat | typing.SupportsIndex = 0.0, gamma: typing.SupportsFloat | typing.SupportsIndex = 0.0, x: typing.Any = None) -> tuple[numpy.ndarray, float, float]:
    """
    XPBD's attachment: C = |p - target|, Δλ = (-C - α̃λ - γ n·(p - x)) / ((1 + γ) w + α̃), Δp = w n Δλ; α̃ = α/h² (α in m/N). Returns (p', violation before, m, λ + Δλ).
    """
def project_balloon(points: typing.Any, triangles: typing.Any, inv_mass: typing.Any, target_volume: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[numpy.typing.NDArray[numpy.float64], float]:
    """
    PBD balloon projection of a closed surface: returns (points', violation V - target before projection, m³).
    """
def project_bending(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any, inv_mass: typing.Annotated[collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], "FixedSize(4)"], rest_angle: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray, float]:
    """
    PBD's dihedral bending projection (Müller et al. 2007, Appendix A; the angle by atan2): C = θ - θ0 over the shared edge (a, b) with opposite vertices c and d, Δp_i = -k w_i C ∇_i C / Σ_j w_j |∇_j C|². Returns (a', b', c', d', violation before, rad).
    """
def project_bending_coloured(points: typing.Any, quads: typing.Any, inv_mass: typing.Any, rest_angle: typing.Any, stiffness: typing.Any = None, alpha_tilde: typing.Any = None, gamma: typing.Any = None, lambda_: typing.Any = None, start: typing.Any = None, independent: bool = True) -> tuple:
    """
    The stepper's coloured bending projection (csb/solver/coloured_bending.hpp) over quads (a, b, c, d) in order, Gauss-Seidel in place: SIMD blocks if independent (the quads must then share no point), else one at a time. PBD with stiffness (default 1), or XPBD if alpha_tilde is given (gamma, lambda_, start: damping, multipliers, sub-step start positions). Returns (points', lambda' or None).
    """
def project_bending_xpbd(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any, inv_mass: typing.Annotated[collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], "FixedSize(4)"], rest_angle: typing.SupportsFloat | typing.SupportsIndex, alpha_tilde: typing.SupportsFloat | typing.SupportsIndex, lambda_: typing.SupportsFloat | typing.SupportsIndex = 0.0, gamma: typing.SupportsFloat | typing.SupportsIndex = 0.0, x: typing.Any = None) -> tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray, float, float]:
    """
    XPBD's dihedral bending projection: C = θ - θ0 over the shared edge (a, b) with opposite vertices c and d, Δλ = (-C - α̃λ - γ Σ ∇C·(p - x)) / ((1 + γ) Σ w |∇C|² + α̃), Δp_i = w_i ∇_i C Δλ; α̃ = α/h² (α in 1/(N m)), γ the damping, x the (4, 3) start positions (default the given ones). Returns (a', b', c', d', violation before, rad, λ + Δλ).
    """
def project_distance(p1: typing.Any, p2: typing.Any, w1: typing.SupportsFloat | typing.SupportsIndex, w2: typing.SupportsFloat | typing.SupportsIndex, rest_length: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, sense: str = '==') -> tuple[numpy.ndarray, numpy.ndarray, float]:
    """
    PBD's distance projection (Müller et al. 2007, Eq. 9-10): C = |p1 - p2| - L, Δp1 = -w1/(w1 + w2) k C n, Δp2 = +w2/(w1 + w2) k C n, n = (p1 - p2)/|p1 - p2|; sense '<=' or '>=' projects only a violated inequality. Also Jakobsen's stick with square roots. Returns (p1', p2', violation before, m).
    """
def project_distance_jakobsen(p1: typing.Any, p2: typing.Any, w1: typing.SupportsFloat | typing.SupportsIndex, w2: typing.SupportsFloat | typing.SupportsIndex, rest_length: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, sense: str = '==') -> tuple[numpy.ndarray, numpy.ndarray, float]:
    """
    Jakobsen's stick without a square root (2001, §4): |d| ≈ (d·d + L²)/(2L), so the correction is (d·d - L²)/(d·d + L²) d shared by inverse mass and scaled by the stiffness. Returns (p1', p2', the approximate violation (d·d - L²)/(2L), m). (With square roots Jakobsen's stick is project_distance.)
    """
def project_distance_xpbd(p1: typing.Any, p2: typing.Any, w1: typing.SupportsFloat | typing.SupportsIndex, w2: typing.SupportsFloat | typing.SupportsIndex, rest_length: typing.SupportsFloat | typing.SupportsIndex, alpha_tilde: typing.SupportsFloat | typing.SupportsIndex, lambda_: typing.SupportsFloat | typing.SupportsIndex = 0.0, gamma: typing.SupportsFloat | typing.SupportsIndex = 0.0, x1: typing.Any = None, x2: typing.Any = None, sense: str = '==') -> tuple[numpy.ndarray, numpy.ndarray, float, float]:
    """
    XPBD's distance projection (Macklin et al. 2016, Eq. 18 and 26): C = |p1 - p2| - L, Δλ = (-C - α̃λ - γ ∇C·(p - x)) / ((1 + γ)(w1 + w2) + α̃), Δp1 = w1 n Δλ, Δp2 = -w2 n Δλ, with α̃ = α/h² (kg⁻¹, α in m/N), γ = αβ/h the damping (x1, x2 the positions at the start of the sub-step; default p1, p2). sense '<=' or '>=' makes it an inequality (λ clamped to its sign). Returns (p1', p2', violation before, λ + Δλ); λ/h² is the force, N.
    """
def project_volume(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any, inv_mass: typing.Annotated[collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], "FixedSize(4)"], rest_volume: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray, float]:
    """
    PBD: returns (a', b', c', d', violation V - V0 before projection, m³).
    """
def project_volume_xpbd(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any, inv_mass: typing.Annotated[collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], "FixedSize(4)"], rest_volume: typing.SupportsFloat | typing.SupportsIndex, alpha_tilde: typing.SupportsFloat | typing.SupportsIndex, lambda_: typing.SupportsFloat | typing.SupportsIndex = 0.0) -> tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray, float, float]:
    """
    XPBD (no damping), α̃ = α/h² in m⁴/kg (α in m⁶/J): returns (a', b', c', d', violation, λ + Δλ).
    """
def tet_volume(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any) -> float:
    """
    Signed volume (1/6)(b - a) x (c - a)·(d - a), m³.
    """
def tet_volume_gradient(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any) -> numpy.typing.NDArray[numpy.float64]:
    """
    (4, 3) gradient of the signed volume, m².
    """
