"""The build: the extension imports, reports its dependencies, and SUNDIALS is linked with KLU."""

import csb


def test_build_info_names_every_dependency():
    info = csb.build_info()
    assert info["csb"] == csb.__version__
    assert info["eigen"].startswith("3.")
    assert int(info["assimp"].split(".")[0]) >= 5
    # Asked of the linked SUNDIALS at run time: the reference integrator's library is wired in.
    assert int(info["sundials"].split(".")[0]) >= 6
    assert info["sundials_klu"] is True


def test_readable_formats_include_the_ones_we_promise():
    exts = set(csb.readable_extensions())
    assert {".obj", ".ply", ".stl", ".gltf", ".glb", ".fbx", ".dae", ".3ds", ".off"} <= exts
