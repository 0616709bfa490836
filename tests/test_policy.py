"""CostPolicy (the "auto" cost policy) driven by set frame times, against a re-statement of its rule written here.

No rendering: each frame asks the policy for (path, timed, watched), and the test feeds back the time it chose for
that frame. The re-statement (``expected_measurement``) follows the rule of foveawarp/policy.py's docstring:
untimed then timed frames of each path, both paths again in the other order when the medians are not clear-cut,
the full path a third time when foveation then wins, each path's estimate the lowest of its blocks' medians, and
foveation chosen only when at least the margin cheaper.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from foveawarp.policy import CostPolicy

P = CostPolicy


def expected_measurement(block_ms, first=True, last=None):
    """The measurement the rule runs for per-block timed frame times ``block_ms`` (block k's j-th timed frame takes
    ``block_ms[k][j % len(block_ms[k])]``), as the first measurement or after the ``last`` (foveated, full)
    estimates. Returns (frames: [(path, timed, block, j)], choice, (foveated, full) estimates, pooled medians)."""
    if first:
        warm, timed = P.WARM, P.TIMED
    else:
        lo, hi = sorted(last)
        warm, timed = P.WARM_AGAIN, (P.TIMED_CLEAR if lo < (1.0 - P.CLEAR) * hi else P.TIMED)
    blocks = [("foveated", warm, timed), ("full", warm, timed)]

    def times(k):
        return [block_ms[k][j % len(block_ms[k])] for j in range(blocks[k][2])]

    def median(k):
        return float(np.median(times(k)))

    fov, full = median(0), median(1)
    lo, hi = sorted((fov, full))
    if not lo < (1.0 - P.CLEAR) * hi:  # not clear-cut: both again, the other order
        blocks += [("full", P.WARM_AGAIN, P.TIMED), ("foveated", P.WARM_AGAIN, P.TIMED)]
        fov, full = min(median(0), median(3)), min(median(1), median(2))
        if fov < (1.0 - P.MARGIN) * full:  # a close win of foveation: the full path a third time
            blocks.append(("full", P.WARM_AGAIN, P.TIMED))
            full = min(full, median(4))
    choice = "foveated" if fov < (1.0 - P.MARGIN) * full else "full"
    frames = [(path, j >= w, k, j - w) for k, (path, w, t) in enumerate(blocks) for j in range(w + t)]
    pooled = tuple(float(np.median(sum((times(k) for k, b in enumerate(blocks) if b[0] == path), [])))
                   for path in ("foveated", "full"))
    return frames, choice, (fov, full), pooled


def drive_measurement(pol, block_ms, start=0, first=True, last=None):
    """Run one measurement of ``pol`` from frame index ``start``, checking each frame's (path, timed) against the
    re-statement and feeding its timed frames their set times; then the decision frame. Returns (the expected
    measurement, the decision frame's (path, timed, watched), the next frame index)."""
    exp = expected_measurement(block_ms, first, last)
    frames = exp[0]
    for i, (path, timed, k, j) in enumerate(frames):
        got = pol.next_frame(start + i)
        assert got[:2] == (path, timed) and not got[2], (i, got, (path, timed, k, j))
        if timed:
            pol.record(path, block_ms[k][j % len(block_ms[k])])
    decision = pol.next_frame(start + len(frames))
    return exp, decision, start + len(frames) + 1


def check_decision(pol, exp, decision, index):
    frames, choice, (fov, full), pooled = exp
    assert decision[0] == choice and not decision[1]
    assert pol.choice == choice
    est = pol.estimates
    assert est["foveated_ms"] == pytest.approx(fov, rel=1e-12) and est["full_ms"] == pytest.approx(full, rel=1e-12)
    assert est["blocks"] == len({k for _, _, k, _ in frames}) and est["measured_at_frame"] == index
    assert pol.reference["foveated_ms"] == pytest.approx(pooled[0]) and pol.reference["full_ms"] == pytest.approx(
        pooled[1])


CASES = {
    # clear-cut either way: two blocks
    "clear_foveated": [[0.5, 0.52, 0.49], [1.0, 1.01, 0.99]],
    "clear_full": [[2.0, 2.1, 1.9], [1.0, 1.01, 0.99]],
    # close, foveation wins: the full path a third time, and it decides (two back-to-back slow full blocks)
    "close_fov_then_full": [[1.0, 1.02, 0.98], [1.2, 1.25, 1.19], [1.22, 1.21, 1.2], [1.01, 1.0, 1.03],
                            [0.9, 0.91, 0.89]],
    "close_fov_kept": [[1.0, 1.01, 0.99], [1.2, 1.22, 1.18], [1.21, 1.2, 1.19], [1.3, 1.31, 1.29], [1.25, 1.24]],
    # close, full resolution the cheaper: four blocks
    "close_full": [[1.0, 1.02, 0.98], [0.98, 0.99, 0.97], [0.97, 0.99, 0.98], [1.01, 1.0, 1.03]],
    # a slow first full block: the second full block's median decides
    "transient_full": [[1.0, 1.02, 0.98], [1.2, 1.25, 1.19], [0.9, 0.91, 0.89], [1.01, 1.0, 1.03]],
    # within the margin: foveation exactly 5 % cheaper is not enough
    "margin_equal": [[0.95], [1.0], [1.0], [0.95]],
    "margin_just_below": [[0.9499], [1.0], [1.0], [0.9499], [1.0]],
    # the clear-cut limit: exactly 25 % cheaper is not clear-cut
    "clear_equal": [[0.75], [1.0], [1.0], [0.75], [1.0]],
    "clear_just_below": [[0.7499], [1.0]],
    "all_zero": [[0.0], [0.0], [0.0], [0.0]],
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_first_measurement_schedule_and_choice(case):
    """The first measurement: WARM untimed + TIMED timed frames of each path, foveated first; the confirming
    blocks when not clear-cut; then the choice with its estimates, reported with the frame and the trigger."""
    pol = CostPolicy("auto")
    exp, decision, nxt = drive_measurement(pol, CASES[case])
    check_decision(pol, exp, decision, nxt - 1)
    assert pol.estimates["trigger"] == "first frames" and pol.estimates["rechecks"] == 0
    nblocks = {"clear_foveated": 2, "clear_full": 2, "clear_just_below": 2, "close_full": 4, "transient_full": 4,
               "margin_equal": 4, "all_zero": 4}.get(case, 5)
    assert pol.estimates["blocks"] == nblocks
    choice = {"clear_foveated": "foveated", "close_fov_kept": "foveated", "margin_just_below": "foveated",
              "clear_equal": "foveated", "clear_just_below": "foveated"}.get(case, "full")
    assert pol.choice == choice
    # the chosen path from then on, every frame watched (wall times)
    for i in range(5):
        assert pol.next_frame(nxt + i) == (choice, False, True)
        pol.watch(1.0)
    assert len(exp[0]) <= CostPolicy.measurement_frames()


def test_measurement_frames_bound():
    assert CostPolicy.measurement_frames() == 2 * (P.WARM + P.TIMED) + 3 * (P.WARM_AGAIN + P.TIMED)


@pytest.mark.parametrize("first_case,second_case", [("clear_foveated", "close_full"), ("close_full", "clear_full"),
                                                    ("close_fov_kept", "clear_just_below")])
def test_later_measurement_every_period(first_case, second_case):
    """A measurement every PERIOD frames after the last began: WARM_AGAIN untimed frames per path and TIMED_CLEAR
    timed ones after clear-cut estimates, else TIMED; the trigger says so; no check acts while the frames agree."""
    pol = CostPolicy("auto")
    exp, decision, nxt = drive_measurement(pol, CASES[first_case])
    last = (pol.estimates["foveated_ms"], pol.estimates["full_ms"])
    choice = pol.choice
    ref = pol.reference
    agree = 0.5 * min(ref["foveated_ms"], ref["full_ms"])  # watched frames cheaper than either: the choice holds
    for i in range(nxt, P.PERIOD):
        assert pol.next_frame(i) == (choice, False, True), i
        pol.watch(agree)
    exp, decision, nxt = drive_measurement(pol, CASES[second_case], start=P.PERIOD, first=False, last=last)
    check_decision(pol, exp, decision, nxt - 1)
    timed = sum(1 for f in exp[0] if f[2] == 0 and f[1])
    lo, hi = sorted(last)
    assert timed == (P.TIMED_CLEAR if lo < (1 - P.CLEAR) * hi else P.TIMED)
    assert sum(1 for f in exp[0] if f[2] == 0 and not f[1]) == P.WARM_AGAIN
    assert pol.length == (P.WARM_AGAIN, timed)
    assert pol.estimates["trigger"] == f"every {P.PERIOD} frames" and pol.estimates["rechecks"] == 0


@pytest.mark.parametrize("choice_case", ["clear_foveated", "clear_full"])
def test_watch_rechecks_a_wrong_choice_no_sooner_than_recheck_min(choice_case):
    """The median of WATCH watched frames that contradicts the choice (foveated frames no cheaper than the full
    path's pooled median; full frames dearer than the foveated one's by the margin) starts the next measurement at
    once, but only at a check at least RECHECK_MIN frames after the last measurement began; a watch within the
    margin or below RECHECK_MIN changes nothing."""
    pol = CostPolicy("auto")
    exp, decision, nxt = drive_measurement(pol, CASES[choice_case])
    choice, ref = pol.choice, dict(pol.reference)
    # the watch begins with the decision frame d: frames d + W (k - 1) .. d + W k - 1 are checked at frame d + W k
    d = nxt - 1
    if choice == "foveated":
        wrong, fine = ref["full_ms"], ref["full_ms"] * (1 - 1e-9)
    else:
        limit = ref["foveated_ms"] / (1 - P.MARGIN)
        wrong, fine = limit * (1 + 1e-9), limit * (1 - 1e-9)
    first_check = d + P.WATCH * math.ceil((P.RECHECK_MIN - d) / P.WATCH)  # the first that may act
    assert first_check - P.WATCH > d  # wrong checks before RECHECK_MIN come first
    pol.watch(wrong)
    f = nxt
    while True:
        path, timed, watched = pol.next_frame(f)
        if pol.rechecks:
            break
        assert (path, timed, watched) == (choice, False, True)
        # wrong times, except for the first check that may act: its frames agree with the choice within the margin
        pol.watch(fine if first_check - P.WATCH <= f < first_check else wrong)
        f += 1
        assert f < P.PERIOD, "no recheck"
    assert f == first_check + P.WATCH
    # the frame at which the check acted is the new measurement's first (foveated, untimed)
    assert (path, timed, watched) == ("foveated", False, False)
    other = "full" if choice == "foveated" else "foveated"
    frames = expected_measurement(CASES["clear_foveated"], first=False,
                                  last=(pol.estimates["foveated_ms"], pol.estimates["full_ms"]))[0]
    assert frames[0][:2] == (path, timed) and pol.length == (P.WARM_AGAIN, P.TIMED_CLEAR)
    for i, (p, t, k, j) in enumerate(frames[1:], start=1):
        assert pol.next_frame(f + i)[:2] == (p, t)
        if t:
            pol.record(p, CASES["clear_foveated"][k][j % len(CASES["clear_foveated"][k])])
    pol.next_frame(f + len(frames))
    est = pol.estimates
    assert est["rechecks"] == 1 and est["measured_at_frame"] == f + len(frames)
    assert est["trigger"] == (f"check: the {choice} frames measured {wrong:.3f} ms (median of {P.WATCH}) against "
                              f"{ref[other + '_ms']:.3f} ms estimated {other}")


def test_watch_within_recheck_min_does_not_remeasure():
    """A wrong watch that has gathered WATCH frames before RECHECK_MIN is dropped (the next check gathers anew)."""
    pol = CostPolicy("auto")
    _, _, nxt = drive_measurement(pol, CASES["clear_foveated"])
    for i in range(nxt, P.RECHECK_MIN):
        assert pol.next_frame(i) == ("foveated", False, True)
        pol.watch(1e6)
    assert pol.rechecks == 0 and len(pol.watched) < P.WATCH


def test_by_events_watches_one_frame_in_watch_every_and_compares_spans():
    """By events the watch takes one frame in WATCH_EVERY and compares GPU spans (``record(span_ms=...)``) with the
    spans' pooled medians; the decision reports both estimates."""
    pol = CostPolicy("auto", by_events=True)
    block_ms = CASES["clear_foveated"]
    frames = expected_measurement(block_ms)[0]
    for i, (p, t, k, j) in enumerate(frames):
        assert pol.next_frame(i) == (p, t, False)
        if t:
            ms = block_ms[k][j % len(block_ms[k])]
            pol.record(p, ms, span_ms=0.5 * ms)
    f = len(frames)
    assert pol.next_frame(f) == ("foveated", False, f % P.WATCH_EVERY == 0)
    est = pol.estimates
    assert est["foveated_gpu_ms"] == pytest.approx(0.5 * est["foveated_ms"])
    assert est["full_gpu_ms"] == pytest.approx(0.5 * est["full_ms"])
    watched = [i for i in range(f + 1, P.RECHECK_MIN) if pol.next_frame(i)[2]]
    assert watched == [i for i in range(f + 1, P.RECHECK_MIN) if i % P.WATCH_EVERY == 0]
    # at RECHECK_MIN: a check of spans below the full path's span median holds the choice, one at it does not
    span_full = pol.reference["full_gpu_ms"]
    for _ in range(P.WATCH):
        pol.watch(span_full * (1 - 1e-9))
    assert pol.next_frame(P.RECHECK_MIN)[0] == "foveated" and pol.rechecks == 0 and pol.watched == []
    for _ in range(P.WATCH):
        pol.watch(span_full)
    assert pol.next_frame(P.RECHECK_MIN + 1) == ("foveated", False, False) and pol.rechecks == 1
    assert pol.estimates["trigger"] == "first frames"  # the new measurement reports its trigger when it decides


@pytest.mark.parametrize("mode", ["foveated", "full"])
def test_forced_modes_never_measure(mode):
    pol = CostPolicy(mode)
    for i in range(3 * CostPolicy.measurement_frames()):
        assert pol.next_frame(i) == (mode, False, False)
    assert pol.estimates == {}
    if mode == "full":
        assert pol.skip_reason() == "policy 'full': every pixel traced"


@pytest.mark.parametrize("mode", ["auto", "foveated", "full"])
def test_no_foveated_path_times_nothing(mode):
    """A configuration without a foveated path (FoveationConfig.enabled False: the loop renders every frame at full
    resolution): nothing timed or watched, no measurement begun; the path named is the mode's ("full" for "full",
    else "foveated", which such a loop renders at full resolution)."""
    pol = CostPolicy(mode)
    for i in range(100):
        assert pol.next_frame(i, foveation=False) == ("full" if mode == "full" else "foveated", False, False)
    assert pol.frame == 0 and pol.estimates == {} and pol.samples == {"foveated": [], "full": []}


def test_mode_switch_and_skip_reason():
    pol = CostPolicy("auto")
    assert pol.skip_reason() == "policy 'auto': timing the full-resolution path"
    drive_measurement(pol, CASES["clear_full"])
    assert pol.skip_reason().startswith("policy 'auto': full resolution is cheaper here (measured 1.000 ms full vs")
    pol.mode = "foveated"
    assert pol.next_frame(10) == ("foveated", False, False)
    pol.mode = "auto"
    assert pol.next_frame(11)[0] == "full"


@pytest.mark.parametrize("bad", ["fast", "", None, 1, True, "Auto"])
def test_bad_mode(bad):
    with pytest.raises(ValueError, match="policy must be one of"):
        CostPolicy(bad)
    pol = CostPolicy()
    with pytest.raises(ValueError, match="policy must be one of"):
        pol.mode = bad
    assert pol.mode == "auto"


@pytest.mark.parametrize("bad", [-1.0, -1e-9, float("nan"), float("inf"), -float("inf"), "1.0x", "1.0", None, True, [1.0]])
def test_bad_times(bad):
    pol = CostPolicy()
    pol.next_frame(0)
    with pytest.raises(ValueError, match=r"^ms must be a finite number"):
        pol.record("foveated", bad)
    if bad is not None:  # span_ms None: no span
        with pytest.raises(ValueError, match=r"^span_ms must be a finite number"):
            pol.record("foveated", 1.0, span_ms=bad)
    with pytest.raises(ValueError, match=r"^ms must be a finite number"):
        pol.watch(bad)
    assert pol.watched == [] and pol.samples == {"foveated": [], "full": []} and pol.spans["foveated"] == []


@pytest.mark.parametrize("bad", ["half", "auto", None, 0])
def test_bad_path(bad):
    with pytest.raises(ValueError, match="path must be one of"):
        CostPolicy().record(bad, 1.0)


def test_zero_time_and_numpy_scalars_accepted():
    pol = CostPolicy()
    pol.watch(0.0)
    pol.watch(np.float32(1.5))
    pol.record("full", np.float64(2.0), span_ms=0)
    assert pol.watched == [0.0, 1.5] and pol.samples["full"] == [(0, 2.0)] and pol.spans["full"] == [(0, 0.0)]


# times on a coarse grid, so that ties, equal medians and the margin's edges come up
_MS = st.one_of(st.sampled_from([0.0, 0.5, 0.75, 0.95, 1.0, 1.05, 1.25, 2.0]),
                st.floats(0.0, 50.0, allow_nan=False, allow_infinity=False))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(_MS, min_size=1, max_size=P.TIMED), min_size=5, max_size=5),
       st.lists(st.lists(_MS, min_size=1, max_size=P.TIMED), min_size=5, max_size=5))
def test_random_timings_follow_the_rule(first, second):
    """For random timings of every block, two measurements in a row (the second one period later) render the
    schedule of the rule, and each picks the path whose estimate the rule picks, with those estimates."""
    pol = CostPolicy("auto")
    exp, decision, nxt = drive_measurement(pol, first)
    check_decision(pol, exp, decision, nxt - 1)
    fov, full = exp[2]
    assert pol.choice == ("foveated" if fov < 0.95 * full else "full")
    last = (pol.estimates["foveated_ms"], pol.estimates["full_ms"])
    # no watch (times never given): the choice stays until the period
    for i in range(nxt, P.PERIOD):
        assert pol.next_frame(i)[:2] == (pol.choice, False)
    exp, decision, nxt = drive_measurement(pol, second, start=P.PERIOD, first=False, last=last)
    check_decision(pol, exp, decision, nxt - 1)
