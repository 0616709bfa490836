"""E34: G-buffer by BVH vs by screen bins: GPU time (CUDA events, median of 30), bin statistics, fields differing."""
import sys, time, json
import numpy as np, warp as wp
wp.config.quiet = True
import foveawarp as fw
from foveawarp.stages.gbuffer import GBufferStage

dev = "cuda:0"
sizes = [(1920, 1080), (3840, 2160)]
names = sys.argv[1].split(",") if len(sys.argv) > 1 else ["cornell", "city", "eyechart", "earth", "bunny", "spot", "teapot", "nefertiti", "ogre"]
caps = [int(c) for c in (sys.argv[2].split(",") if len(sys.argv) > 2 else ["64"])]
res = []

def timed(fn, reps=30):
    for _ in range(3):
        fn()
    wp.synchronize_device(dev)
    ts = []
    for _ in range(reps):
        e0 = wp.Event(dev, enable_timing=True); e1 = wp.Event(dev, enable_timing=True)
        wp.record_event(e0); fn(); wp.record_event(e1)
        wp.synchronize_device(dev)
        ts.append(wp.get_event_elapsed_time(e0, e1))
    return float(np.median(ts))

def host_timed(fn, reps=30):
    wp.synchronize_device(dev)
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter(); fn(); t1 = time.perf_counter()
        wp.synchronize_device(dev)
        ts.append((t1 - t0) * 1e6)
    return float(np.median(ts))

for name in names:
    scene = fw.load_scene(name)
    for (W, H) in sizes:
        loop = fw.FrameLoop(scene, W, H, device=dev, graph=False)
        cam = scene.camera
        loop.render_reference(cam)
        wp.synchronize_device(dev)
        g = loop.gbuffer
        bvh = loop.gbuffer_stage
        t_bvh = timed(lambda: bvh.run(g, cam, cam))
        h_bvh = host_timed(lambda: bvh.run(g, cam, cam))
        a = {k: v.copy() for k, v in g.numpy().items()}
        for cap in caps:
            st = GBufferStage(loop.dscene, W, H, dev, primary="bins", bin_cap=cap)
            t_bins = timed(lambda: st.run(g, cam, cam))
            h_bins = host_timed(lambda: st.run(g, cam, cam))
            b = g.numpy()
            cnt = st.bin_counts()
            diffs = {k: int(np.sum(np.any((a[k] != b[k]).reshape(H, W, -1), axis=-1))) for k in a if a[k].shape[:2] == (H, W)}
            r = dict(scene=name, width=W, height=H, tris=int(loop.dscene.indices.shape[0] // 3), cap=cap,
                     bvh_ms=t_bvh, bins_ms=t_bins, host_bvh_us=h_bvh, host_bins_us=h_bins,
                     bins_max=int(cnt.max()), bins_mean=float(cnt.mean()), overflow_bins=int((cnt > cap).sum()),
                     nbins=int(cnt.size), diff_px={k: v for k, v in diffs.items() if v})
            res.append(r)
            print(f"{name:10s} {W}x{H} cap {cap:4d}: bvh {t_bvh:.3f} ms  bins {t_bins:.3f} ms ({t_bvh/t_bins:.2f}x)  host {h_bvh:.0f}/{h_bins:.0f} us  "
                  f"bins max {r['bins_max']} mean {r['bins_mean']:.1f} overflow {r['overflow_bins']}/{r['nbins']}  diff {r['diff_px']}", flush=True)
        del loop
json.dump(res, open(sys.argv[3] if len(sys.argv) > 3 else "e34.json", "w"), indent=1)
