import time

import numpy as np

from ltmap_cli.core.config import MapConfig
from ltmap_cli.core.layers import LayeredMap
from ltmap_cli.io.mapfile import read_map_yaml
from ltmap_cli.io.state import read_state

arrays,_ = read_state('/tmp/cmp/snapshots/state_final.npz')
m = LayeredMap(MapConfig()); m.load_state_arrays(arrays)
k = m.occupied_keys("O")
pts = (k[:, :2] + 0.5) * 0.05
pts = np.unique(np.round(pts, 3), axis=0)
print("our occupied columns", len(pts))
g = read_map_yaml('/work/shared/real_logs/comprobo22_maps/mac_1st_floor_final.yaml')
print(g.data.shape, g.resolution, g.origin)
res = 0.06
occ = g.data == 100
rows, cols = np.nonzero(occ)
mp = np.stack([g.origin[0] + (cols + 0.5) * g.resolution, g.origin[1] + (rows + 0.5) * g.resolution], 1)
x0, y0 = mp.min(0) - 3; x1, y1 = mp.max(0) + 3
W = int((x1 - x0) / res) + 1; H = int((y1 - y0) / res) + 1
M = np.zeros((H, W)); ii = ((mp - [x0, y0]) / res).astype(int); M[ii[:, 1], ii[:, 0]] = 1
# dilate by 1 cell
D = M.copy()
for dy in (-1, 0, 1):
    for dx in (-1, 0, 1):
        D = np.maximum(D, np.roll(np.roll(M, dy, 0), dx, 1))
FD = np.fft.rfft2(D)
best = (-1,)
t = time.time()
for yaw_deg in np.arange(0, 360, 1.0):
    a = np.radians(yaw_deg); c, s = np.cos(a), np.sin(a)
    q = pts @ np.array([[c, s], [-s, c]])
    q = q - q.min(0)
    P = np.zeros((H, W)); jj = (q / res).astype(int)
    if jj[:, 0].max() >= W or jj[:, 1].max() >= H: continue
    P[jj[:, 1], jj[:, 0]] = 1
    corr = np.fft.irfft2(FD * np.conj(np.fft.rfft2(P)), s=D.shape)
    idx = np.unravel_index(np.argmax(corr), corr.shape)
    if corr[idx] > best[0]:
        best = (corr[idx], yaw_deg, idx, q.min(0) if False else None, pts @ np.array([[c, s], [-s, c]]))
print("coarse", best[0], best[1], time.time() - t)
score, yaw_deg, (dy, dx), _, rot = best
# translation: map point = rot - rot.min + shift*res + [x0,y0]
tx = x0 + dx * res - rot.min(0)[0]; ty = y0 + dy * res - rot.min(0)[1]
print("yaw", yaw_deg, "t", tx, ty, "fraction", score / len(pts))
# refine: small grid search maximizing fraction of points within 1 map cell (0.06 dilated) at finer res
from itertools import product


def frac(yaw, tx, ty):
    a = np.radians(yaw); c, s = np.cos(a), np.sin(a)
    q = pts @ np.array([[c, s], [-s, c]]) + [tx, ty]
    j = np.floor((q - [g.origin[0], g.origin[1]]) / g.resolution).astype(int)
    ok = (j[:, 0] >= 0) & (j[:, 0] < g.data.shape[1]) & (j[:, 1] >= 0) & (j[:, 1] < g.data.shape[0])
    Dm = occ.copy()
    return j, ok
occD = occ.copy()
for dy in (-2,-1, 0, 1,2):
    for dx in (-2,-1, 0, 1,2):
        occD |= np.roll(np.roll(occ, dy, 0), dx, 1)
def score2(yaw, tx, ty):
    a = np.radians(yaw); c, s = np.cos(a), np.sin(a)
    q = pts @ np.array([[c, s], [-s, c]]) + [tx, ty]
    j = np.floor((q - [g.origin[0], g.origin[1]]) / g.resolution).astype(int)
    ok = (j[:, 0] >= 0) & (j[:, 0] < g.data.shape[1]) & (j[:, 1] >= 0) & (j[:, 1] < g.data.shape[0])
    return occD[j[ok, 1], j[ok, 0]].sum() / len(pts)
b = (score2(yaw_deg, tx, ty), yaw_deg, tx, ty)
for step_a, step_t in ((0.5, 0.04), (0.2, 0.02), (0.1, 0.01)):
    improved = True
    while improved:
        improved = False
        for da, ddx, ddy in product((-step_a, 0, step_a), (-step_t, 0, step_t), (-step_t, 0, step_t)):
            sc = score2(b[1] + da, b[2] + ddx, b[3] + ddy)
            if sc > b[0] + 1e-9:
                b = (sc, b[1] + da, b[2] + ddx, b[3] + ddy); improved = True
print("refined fraction within 2 cells (0.06 m):", b)
for dyaw in (2, 5, 10, 30):
    print("wrong by", dyaw, "deg:", score2(b[1] + dyaw, b[2], b[3]))
print("shifted 0.3 m:", score2(b[1], b[2] + 0.3, b[3]))
