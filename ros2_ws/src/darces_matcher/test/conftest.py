"""Fixtures shared by the matcher tests: a clustered 120-ROI test GN and its matcher."""

from __future__ import annotations

import pytest

from darces_matcher.gn_generator import GnSpec, generate_gn
from darces_matcher.matcher import Matcher
from roi_network.network import RoiNetwork


@pytest.fixture(scope="module")
def gn() -> RoiNetwork:
    return generate_gn(GnSpec(n_rois=120), seed=3)


@pytest.fixture(scope="module")
def matcher(gn: RoiNetwork) -> Matcher:
    return Matcher(gn)
