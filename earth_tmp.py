import sys, math, numpy as np, cv2, dataclasses
sys.path.insert(0,'.')
from tests.moon_frames import moon_over_earth
from vision.config import VisionConfig, FramePrior
from vision.frontend import process_frame
rng = np.random.default_rng(3)
c = VisionConfig()
cfg = dataclasses.replace(c, earth=dataclasses.replace(c.earth, enabled=False), sun=dataclasses.replace(c.sun, enabled=False), moon=dataclasses.replace(c.moon, enabled=True))
E=[];S=[];N=int(sys.argv[1])
for i in range(N):
    d = rng.uniform(8, 60); k = rng.uniform(0.2, 1.0)
    f = moon_over_earth(rng, d, k, seed=i)
    b = f.image.mean(axis=2)
    from vision.camera import project
    uv = project(f.camera, f.moon_c); u, v = np.rint(uv).astype(int)
    r = int(f.alpha * f.camera.fx) + 2
    peak = b[max(0,v-r):v+r+1, max(0,u-r):u+r+1].max()
    res = process_frame(f.image, f.camera, cfg, prior=FramePrior(sun_c=f.sun_c, moon_alpha=f.alpha))
    rec = res.record("moon")
    err = math.degrees(math.acos(min(1, float(rec.e_c @ f.moon_c)))) if rec else None
    ring = np.concatenate([b[max(0,v-r-3), max(0,u-r):u+r+1], b[min(b.shape[0]-1,v+r+3), max(0,u-r):u+r+1]])
    print(i, f"d={d:.0f} k={k:.2f} peak={peak:.0f} median={np.median(b):.0f} bg={np.median(ring):.0f} p5={np.percentile(b,5):.0f}", "err=%.4f 3sig=%.4f" % (err, 3*rec.sigma_deg) if rec else res.reasons["moon"])
    if rec: E.append(err); S.append(3*rec.sigma_deg)
    if i in (3, 7): cv2.imwrite(f"/tmp/moe_{i}.png", f.image)
E=np.array(E);S=np.array(S)
print(f"found {len(E)}/{N} rms {np.sqrt(np.mean(E**2)):.4f} contained {np.mean(E<S):.3f}")
