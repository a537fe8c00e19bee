"""Test-wide settings.

OpenMP spin-waiting (torch's default) makes multi-threaded kernels several times slower on small shared
machines; passive waiting must be chosen before torch is first imported, hence here.
"""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def tiny_reference(tmp_path_factory):
    """The tiny scene and the products of one undisturbed ``hybridsplat run`` on it: (scene, products, seconds)."""
    from project_runs import products, run_to_end

    from data_synth import generate_scene

    root = tmp_path_factory.mktemp("tiny_reference")
    scene = generate_scene("tiny", root / "scene", seed=0)
    seconds = run_to_end(scene, root / "reference")
    return scene, products(root / "reference"), seconds
