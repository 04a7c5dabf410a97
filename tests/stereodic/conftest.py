"""Shared data of the stereo DIC tests."""

import pytest

from scanners.sim.dic import DicState
from tests.stereodic.dic_cases import simulate_dic_with_rig


@pytest.fixture(scope="session")
def dic_sim(tmp_path_factory):
    """A small simulated stereo DIC dataset (240x192, states: reference, translation, 1 % tension) with
    its rig and truth."""
    root = tmp_path_factory.mktemp("dic_sim")
    states = [DicState("reference"), DicState("translation", translation_mm=(0.6, -0.4, 1.2)),
              DicState("tension", stretch=(1.01, 0.997))]
    simulate_dic_with_rig(root, states, width=240, height=192, supersample=2)
    return root
