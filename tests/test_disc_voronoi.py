"""The "disc" Voronoi variant (ReconstructionConfig.jfa_variant = "disc"): the exact nearest seed by a
distance-ordered scan of the disc that the jitter-block guarantee bounds, checked against a brute-force k-d tree
(SciPy) and, through the Sibson gather, against Park's exact scatter given the same nearest map."""

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

import foveawarp as fw
from foveawarp.stages.reconstruct import ReconstructStage, disc_offsets_for_block, jfa_steps


def guaranteed_mask(rng, h, w, block, density):
    """A random seed mask with at least one seed in every aligned block x block tile (partial ones included)."""
    m = (rng.random((h, w)) < density).astype(np.uint8)
    for ty in range(0, h, block):
        for tx in range(0, w, block):
            t = m[ty:ty + block, tx:tx + block]
            if t.sum() == 0:
                t[rng.integers(t.shape[0]), rng.integers(t.shape[1])] = 1
    return m


def brute_nearest_dist(mask):
    h, w = mask.shape
    seeds = np.argwhere(mask)[:, ::-1]
    pix = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2)
    d, _ = cKDTree(seeds).query(pix)
    return d.reshape(h, w)


def run_disc(mask, block, device, colors=None):
    h, w = mask.shape
    stage = ReconstructStage(w, h, fw.ReconstructionConfig(jfa_variant="disc"), block, device)
    rng = np.random.default_rng(0)
    col = colors if colors is not None else rng.random((h, w, 3)).astype(np.float32)
    cin = wp.array(col, dtype=wp.vec3, device=device)
    out = wp.zeros((h, w), dtype=wp.vec3, device=device)
    stage.run(cin, wp.array(mask, dtype=wp.uint8, device=device), out)
    return stage, cin, out


@pytest.mark.parametrize("block", [1, 2, 4, 5])
def test_disc_offsets_cover_the_bound_in_distance_order(block):
    offs = disc_offsets_for_block(block)
    r2 = 2 * (block - 1) ** 2
    brute = {(dx, dy) for dx in range(-64, 65) for dy in range(-64, 65) if 0 < dx * dx + dy * dy <= r2}
    assert {tuple(o) for o in offs} == brute and len(offs) == len(brute)
    d2 = (offs ** 2).sum(axis=1) if len(offs) else np.zeros(0)
    assert (np.diff(d2) >= 0).all()
    assert jfa_steps(64, 48, "disc") == []


@settings(max_examples=25, deadline=None)
@given(h=st.integers(1, 40), w=st.integers(1, 40), block=st.integers(1, 7), density=st.floats(0.0, 0.5),
       seed=st.integers(0, 2**31 - 1))
def test_disc_nearest_is_exact_under_the_block_guarantee(h, w, block, density, seed):
    rng = np.random.default_rng(seed)
    mask = guaranteed_mask(rng, h, w, block, density)
    stage, _, out = run_disc(mask, block, "cpu")
    near = stage.nearest.numpy()
    ys, xs = np.mgrid[0:h, 0:w]
    got = np.sqrt((near[..., 0] - xs) ** 2 + (near[..., 1] - ys) ** 2)
    assert np.array_equal(got, brute_nearest_dist(mask))  # exact: integer squared distances
    assert (mask[near[..., 1], near[..., 0]] == 1).all()
    seed_pix = mask.astype(bool)
    assert (near[seed_pix] == np.stack([xs, ys], -1)[seed_pix]).all()
    assert int(stage.unreached.numpy()[0]) == 0
    assert np.isfinite(out.numpy()).all()


def test_disc_matches_on_every_device(device):
    rng = np.random.default_rng(3)
    mask = guaranteed_mask(rng, 45, 61, 4, 0.08)
    stage, _, out = run_disc(mask, 4, device)
    ref_stage, _, ref_out = run_disc(mask, 4, "cpu")
    np.testing.assert_array_equal(stage.nearest.numpy(), ref_stage.nearest.numpy())
    np.testing.assert_allclose(out.numpy(), ref_out.numpy(), rtol=0, atol=1e-6)


@pytest.mark.parametrize("block", [2, 4, 7])
def test_disc_scan_reads_a_strided_mask(device, block):
    """The scan (native code: one address per pixel, offsets added to it) follows the mask's row and column
    strides: a view taking every other column of a wider array, starting one row down, gives the brute-force
    nearest seeds of the view, at the image border and inside it."""
    rng = np.random.default_rng(11 + block)
    h, w = 37, 45
    mask = guaranteed_mask(rng, h, w, block, 0.05)
    big = np.full((h + 1, 2 * w), 7, np.uint8)  # seeds everywhere outside the view: a wrong stride finds them
    big[1:, ::2] = mask
    view = wp.array(big, dtype=wp.uint8, device=device)[1:, ::2]
    assert not view.is_contiguous and view.shape == (h, w)
    stage = ReconstructStage(w, h, fw.ReconstructionConfig(jfa_variant="disc"), block, device)
    stage.run_jfa(view)
    near = stage.nearest.numpy()
    ys, xs = np.mgrid[0:h, 0:w]
    got = np.sqrt((near[..., 0] - xs) ** 2 + (near[..., 1] - ys) ** 2)
    assert np.array_equal(got, brute_nearest_dist(mask))
    assert (mask[near[..., 1], near[..., 0]] == 1).all()


@pytest.mark.parametrize("block", [2, 4, 6])
def test_disc_scan_takes_the_first_seed_in_offset_order(device, block):
    """Among equally near seeds the scan returns the first in ``disc_offsets_for_block`` order (squared length,
    then dy, then dx), inside the image (four reads in flight) and at its border alike: a NumPy scan of the same
    offsets picks the same seed for every pixel. Dense masks make ties common."""
    rng = np.random.default_rng(21 + block)
    h, w = 33, 41
    offs = disc_offsets_for_block(block)
    for density in (0.05, 0.3, 0.6):
        mask = guaranteed_mask(rng, h, w, block, density)
        stage = ReconstructStage(w, h, fw.ReconstructionConfig(jfa_variant="disc"), block, device)
        stage.run_jfa(wp.array(mask, dtype=wp.uint8, device=device))
        near = stage.nearest.numpy()
        exp = np.full((h, w, 2), -1, np.int32)
        for y in range(h):
            for x in range(w):
                if mask[y, x]:
                    exp[y, x] = (x, y)
                    continue
                for dx, dy in offs:
                    xx, yy = x + dx, y + dy
                    if 0 <= xx < w and 0 <= yy < h and mask[yy, xx]:
                        exp[y, x] = (xx, yy)
                        break
        np.testing.assert_array_equal(near, exp)


def test_disc_sibson_equals_the_exact_scatter_on_its_nearest_map(device):
    rng = np.random.default_rng(5)
    h, w, block = 48, 64, 4
    mask = guaranteed_mask(rng, h, w, block, 0.1)
    stage, cin, out = run_disc(mask, block, device)
    exact = ReconstructStage(w, h, fw.ReconstructionConfig(), block, device, exact_sibson=True)
    ref = wp.zeros((h, w), dtype=wp.vec3, device=device)
    exact.run_interpolate(cin, ref, nearest=stage.nearest)
    np.testing.assert_allclose(out.numpy(), ref.numpy(), rtol=1e-5, atol=1e-6)


def test_disc_without_the_guarantee_counts_the_pixels_it_cannot_reach():
    h, w, block = 30, 40, 3
    mask = np.zeros((h, w), np.uint8)
    mask[2, 3] = 1  # one seed: most pixels lie beyond the disc of radius 2 sqrt(2)
    stage, _, out = run_disc(mask, block, "cpu")
    d = brute_nearest_dist(mask)
    beyond = np.rint(d * d) > 2 * (block - 1) ** 2  # integer squared distances
    near = stage.nearest.numpy()
    assert (near[beyond] == -1).all() and (near[~beyond] >= 0).all()
    assert int(stage.unreached.numpy()[0]) == int(beyond.sum())
    assert np.isfinite(out.numpy()).all()


def test_frame_loop_with_the_disc_variant_stays_close_to_jfa():
    from foveawarp.metrics import psnr

    w, h = 96, 64
    imgs = {}
    for v in ("1+jfa", "disc"):
        cfg = fw.Config().with_(reconstruction={"jfa_variant": v})
        loop = fw.FrameLoop("cornell", w, h, config=cfg, device="cpu", timing=False, policy="foveated")
        for i in range(3):
            f = loop.render(loop.scene.camera_at(0.1 * i), gaze_px=(30.0, 30.0), time=0.1 * i)
        imgs[v] = f.image.numpy()
        assert int(loop.reconstruct.unreached.numpy()[0]) == 0
    assert psnr(imgs["1+jfa"], imgs["disc"]) > 40.0


def test_auto_variant_resolves_by_guarantee(device):
    """jfa_variant "auto" (the default) runs "disc" in a FrameLoop (its masks hold the block guarantee) and
    "1+jfa" in a ReconstructStage on its own (arbitrary masks); the FrameLoop's image equals the explicit
    variant's."""
    import foveawarp as fw
    from foveawarp.config import JFA_VARIANTS, resolve_voronoi_variant
    from foveawarp.stages.reconstruct import ReconstructStage, jfa_steps

    assert fw.Config().reconstruction.jfa_variant == "auto"
    assert resolve_voronoi_variant("auto", True) == "disc"
    assert resolve_voronoi_variant("auto", False) == "1+jfa"
    for v in JFA_VARIANTS + ("disc",):
        assert resolve_voronoi_variant(v, True) == v
    with pytest.raises(ValueError, match="jfa_variant"):
        resolve_voronoi_variant("voronoi", True)
    assert jfa_steps(64, 48, "auto") == jfa_steps(64, 48, "1+jfa")
    assert ReconstructStage(32, 24, device=device).variant == "1+jfa"
    scene = fw.load_scene("cornell")
    imgs = {}
    for v in ("auto", "disc"):
        loop = fw.FrameLoop(scene, 80, 48, config=fw.Config().with_(reconstruction={"jfa_variant": v}),
                            device=device)
        for i in range(2):
            f = loop.render(scene.camera_at(i / 30), gaze_px=(30.0 + 4 * i, 20.0))
        assert loop.reconstruct.variant == "disc"
        imgs[v] = f.numpy().copy()
    np.testing.assert_array_equal(imgs["auto"], imgs["disc"])
