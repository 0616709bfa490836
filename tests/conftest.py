"""Shared fixtures: the Warp devices to test on (CPU always; CUDA when present)."""

import os

import numpy as np
import pytest
import warp as wp

wp.config.quiet = True
wp.init()


def _devices():
    env = os.environ.get("FOVEAWARP_TEST_DEVICES")
    if env:
        return [d.strip() for d in env.split(",") if d.strip()]
    devs = ["cpu"]
    if wp.is_cuda_available():
        devs.append("cuda:0")
    return devs


DEVICES = _devices()


def pytest_collection_modifyitems(config, items):
    if wp.is_cuda_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device")
    for item in items:
        if "needs_cuda" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(params=DEVICES)
def device(request):
    """Each test that takes ``device`` runs once per available device."""
    return request.param


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
