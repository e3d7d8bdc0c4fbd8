# Compares GPU-drawn frames with llvmpipe frames of the same runs (made on the CPU host with the
# same binary and input; the simulation is thread-count independent, so only the rasteriser differs).
import sys, os, hashlib
import numpy as np
from PIL import Image
ref, runs = sys.argv[1], sys.argv[2]
for scene in sorted(os.listdir(ref)):
    for f in sorted(os.listdir(os.path.join(ref, scene))):
        a = np.asarray(Image.open(os.path.join(ref, scene, f)).convert('RGBA')).astype(int)
        p = os.path.join(runs, scene, 'frames', f)
        if not os.path.exists(p):
            print(f'{scene}/{f}: missing on gpu'); continue
        b = np.asarray(Image.open(p).convert('RGBA')).astype(int)
        if a.shape != b.shape:
            print(f'{scene}/{f}: shape {a.shape} vs {b.shape}'); continue
        d = np.abs(a - b)[..., :3].max(axis=2)
        print(f'{scene}/{f}: {a.shape[1]}x{a.shape[0]} identical={int((d==0).mean()*1000)/10}% '
              f'diff>8: {100*(d>8).mean():.3f}% diff>32: {100*(d>32).mean():.3f}% mean|d|={np.abs(a-b)[...,:3].mean():.3f} max={d.max()}')
