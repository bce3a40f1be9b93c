"""
The constraint kernels on single constraints (for tests and teaching).
"""
from __future__ import annotations
import collections.abc
import numpy
import typing
__all__: list[str] = ['dihedral_angle', 'dihedral_angle_gradient', 'project_attachment', 'project_bending', 'project_distance']
def dihedral_angle(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any) -> float:
    """
    Signed dihedral angle across edge (a, b), rad.
    """
def dihedral_angle_gradient(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any) -> typing.Any:
    """
    (4, 3) gradient, rad/m; None if degenerate.
    """
def project_attachment(p: typing.Any, w: typing.SupportsFloat | typing.SupportsIndex, target: typing.Any, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[numpy.ndarray, float]:
    ...
def project_bending(a: typing.Any, b: typing.Any, c: typing.Any, d: typing.Any, inv_mass: typing.Annotated[collections.abc.Sequence[typing.SupportsFloat | typing.SupportsIndex], "FixedSize(4)"], rest_angle: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0) -> tuple[numpy.ndarray, numpy.ndarray, numpy.ndarray, numpy.ndarray, float]:
    """
    Returns (a', b', c', d', violation before projection).
    """
def project_distance(p1: typing.Any, p2: typing.Any, w1: typing.SupportsFloat | typing.SupportsIndex, w2: typing.SupportsFloat | typing.SupportsIndex, rest_length: typing.SupportsFloat | typing.SupportsIndex, stiffness: typing.SupportsFloat | typing.SupportsIndex = 1.0, sense: str = '==') -> tuple[numpy.ndarray, numpy.ndarray, float]:
    """
    Returns (p1', p2', violation before projection).
    """
