"""The csb.AnimationWarning of a skinned file loaded as a plain mesh (a cloth, say) says what csb
does use of the animation: a mesh collider deforms with it (PbdStepper.deform_collider, a scene's
animation = true)."""

from __future__ import annotations

from pathlib import Path

import pytest

import csb


def test_the_warning_for_a_skinned_file_names_the_deforming_collider():
    gltf = Path(csb.__file__).parent / "scenes" / "meshes" / "waving_character.gltf"
    with pytest.warns(csb.AnimationWarning) as record:
        csb.load_mesh(gltf)
    message = str(record[0].message)
    assert "skinned mesh(es)" in message and "rest pose" in message, message
    assert "mesh collider deforms with its skeleton" in message, message
    assert "PbdStepper.deform_collider" in message and 'animation = true' in message, message
    assert "csb.load_animation" in message, message
