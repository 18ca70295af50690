import sys, os, shutil, numpy as np, gmsh
sys.path.insert(0, '/work/wt-indep/tests/generators')
import truthfem as tf
src, dst = sys.argv[1], sys.argv[2]
if os.path.exists(dst): shutil.rmtree(dst)
shutil.copytree(src, dst, ignore=shutil.ignore_patterns('diagnosis', 'truth.json'))
gmsh.initialize(); gmsh.option.setNumber("General.Terminal", 0); gmsh.open(os.path.join(src, 'mesh.msh'))
tags, coords, _ = gmsh.model.mesh.getNodes(); X = coords.reshape(-1, 3)
idx = {int(t): i for i, t in enumerate(tags)}
_, en = gmsh.model.mesh.getElementsByType(4); T = np.vectorize(idx.__getitem__)(en.reshape(-1, 4).astype(np.int64)); gmsh.finalize()
F = tf.boundary_faces(T)
A, B, C = X[F[:, 0]], X[F[:, 1]], X[F[:, 2]]
def closest(p):
    # brute force: sample-free exact closest point on each triangle (Ericson), pick the nearest
    best, bd = None, 1e9
    for a, b, c in zip(A, B, C):
        ab, ac, ap = b - a, c - a, p - a
        d1, d2 = ab @ ap, ac @ ap
        if d1 <= 0 and d2 <= 0: q = a
        else:
            bp = p - b; d3, d4 = ab @ bp, ac @ bp
            if d3 >= 0 and d4 <= d3: q = b
            else:
                vc = d1 * d4 - d3 * d2
                if vc <= 0 and d1 >= 0 and d3 <= 0: q = a + d1 / (d1 - d3) * ab
                else:
                    cp = p - c; d5, d6 = ab @ cp, ac @ cp
                    if d6 >= 0 and d5 <= d6: q = c
                    else:
                        vb = d5 * d2 - d1 * d6
                        if vb <= 0 and d2 >= 0 and d6 <= 0: q = a + d2 / (d2 - d6) * ac
                        else:
                            va = d3 * d6 - d5 * d4
                            if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0: q = b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
                            else:
                                den = 1 / (va + vb + vc); q = a + ab * vb * den + ac * vc * den
        d = np.linalg.norm(p - q)
        if d < bd: bd, best = d, q
    return best
lines = open(os.path.join(src, 'markers.csv')).read().strip().splitlines()
off = {}
for ln in lines[1:]:
    k, x, y, z = ln.split(','); p = np.array([float(x), float(y), float(z)])
    off[k] = p - closest(p)
print('offset rms um', 1e6 * np.sqrt(np.mean([o @ o for o in off.values()])))
out = ['measurement,marker,x,y,z']
for ln in open(os.path.join(src, 'measurements.csv')).read().strip().splitlines()[1:]:
    m, k, x, y, z = ln.split(','); p = np.array([float(x), float(y), float(z)]) - off[k]
    out.append(f'{m},{k},{p[0]:.9e},{p[1]:.9e},{p[2]:.9e}')
open(os.path.join(dst, 'measurements.csv'), 'w').write('\n'.join(out) + '\n')
