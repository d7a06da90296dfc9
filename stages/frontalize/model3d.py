"""The speaker's 3D face model (paper 000 §3.2.1, after Suwajanakorn et al. 2014).

1. Start shape: the speaker's own mean frontal 2D landmark shape, given depth by an
   anthropometric prior — or, when the footage rotates the head enough for depth to be
   observable, by Tomasi–Kanade factorisation of the rigid landmarks. Which one is chosen is
   decided by the conditioning of the measurement matrix (s3 / s4, see ``conditioning``).
2. Refinement: pycolmap bundle adjustment of the rigid landmarks over sampled frames (poses and
   points free, intrinsics fixed), then the non-rigid points (mouth, jaw) triangulated with
   the poses held constant. On a short clip with little head rotation depth is unobservable and
   that free fit can run off (points metres along their rays, a depth-inverted face); so it is
   compared, by the per-frame PnP error it gives, with its depth flip, a fit regularised towards
   the start shape (``refine_with_prior``) and the start itself, and the best face is kept.
3. Canonical frame: origin between the outer eye corners, x along the eye line, z into the
   head (normal of the face plane), y down; scaled so the outer-eye-corner distance is 90 mm.
"""
from __future__ import annotations

import logging

import numpy as np

from pipeline.face.dlib_face import IOD_MM, LEFT_EYE_OUTER as LEO, RIGHT_EYE_OUTER as REO
from pipeline.face.geometry import rotation, solve_pose

log = logging.getLogger("lipsynth.frontalize")

# Rigid landmarks: upper jaw contour, brows, nose, eye corners (eyelids blink, mouth/jaw move).
RIGID = np.array([0, 1, 15, 16] + list(range(17, 36)) + [36, 39, 42, 45])
MOUTH = np.arange(48, 68)
LIP_MIDLINE = np.array([51, 62, 66, 57])      #: outer and inner lip centres, top to bottom
MAX_LIP_STEP_MM = 20.0                        #: the prior's mid-line spans 6 mm; an open jaw adds a few
MAX_DEPTH_MM = 1.5 * IOD_MM                   #: rigid points' depth extent: the prior's ≈ 75 mm (nose tip to the
                                              #: jaw's top), a person's ≈ 70–100; a stretched fit (the bas-relief
                                              #: ambiguity of a face that barely turns) reached 146

# Anthropometric depth prior (mm behind the nose tip) for the 68 iBUG landmarks of an adult face.
PRIOR_DEPTH = np.array(
    [95, 90, 82, 70, 56, 42, 32, 25, 22, 25, 32, 42, 56, 70, 82, 90, 95,     # jaw 0-16
     38, 31, 26, 23, 22, 22, 23, 26, 31, 38,                                 # brows 17-26
     22, 16, 9, 0, 14, 11, 9, 11, 14,                                        # nose 27-35
     38, 32, 31, 28, 31, 32, 28, 31, 32, 38, 32, 31,                         # eyes 36-47
     28, 22, 17, 14, 17, 22, 28, 25, 20, 17, 20, 25,                         # outer lip 48-59
     26, 19, 17, 19, 26, 19, 18, 19], np.float64)                            # inner lip 60-67


def similarity_align(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares similarity transform of (P, 2) ``src`` onto ``dst``; returns transformed src."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, s, vt = np.linalg.svd(a.T @ b)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    scale = s.sum() / np.sum(a ** 2)
    return (a @ r) * scale + md


def mean_shape_2d(landmarks: np.ndarray, iters: int = 3) -> np.ndarray:
    """Generalised Procrustes mean of (F, 68, 2) landmarks, scaled to IOD = IOD_MM, eyes centred."""
    ref = landmarks[0].astype(np.float64)
    for _ in range(iters):
        aligned = np.stack([similarity_align(lm[RIGID], ref[RIGID]) for lm in landmarks])
        full = np.stack([_apply_similarity(lm, lm[RIGID], al) for lm, al in zip(landmarks, aligned)])
        ref = full.mean(0)
    iod = np.linalg.norm(ref[LEO] - ref[REO])
    centre = (ref[LEO] + ref[REO]) / 2
    angle = np.arctan2(*(ref[LEO] - ref[REO])[::-1])
    c, s = np.cos(-angle), np.sin(-angle)
    return ((ref - centre) @ np.array([[c, s], [-s, c]])) * (IOD_MM / iod)


def _apply_similarity(points, src, dst_of_src):
    """Apply to ``points`` the similarity that maps ``src`` to ``dst_of_src``."""
    ms, md = src.mean(0), dst_of_src.mean(0)
    a, b = src - ms, dst_of_src - md
    scale_rot = np.linalg.lstsq(a, b, rcond=None)[0]
    return (points - ms) @ scale_rot + md


def prior_shape(mean2d: np.ndarray) -> np.ndarray:
    """(68, 3) start shape: the speaker's mean 2D shape plus the anthropometric depth prior (mm)."""
    z = PRIOR_DEPTH - PRIOR_DEPTH[[REO, LEO]].mean()   # depth relative to the outer eye corners
    return np.column_stack([mean2d, z])


def conditioning(landmarks: np.ndarray) -> float:
    """s3 / s4 of the registered, centred rigid-landmark measurement matrix (2F × P).

    Under an affine camera the matrix has rank 3; its third singular value carries the depth
    information and grows with head rotation, the fourth is noise. A ratio near 1 means depth
    cannot be recovered from this footage.
    """
    pts = landmarks[:, RIGID].astype(np.float64)
    pts = pts - pts.mean(1, keepdims=True)
    pts /= np.linalg.norm(pts, axis=(1, 2), keepdims=True)
    w = pts.transpose(0, 2, 1).reshape(-1, len(RIGID))
    s = np.linalg.svd(w, compute_uv=False)
    return float(s[2] / max(s[3], 1e-12))


def factorize(landmarks: np.ndarray) -> np.ndarray:
    """Tomasi–Kanade affine factorisation with metric upgrade → (68, 3) shape.

    The mirror ambiguity is resolved in the canonical frame (chin below the nose, nose toward
    the viewer).
    """
    pts = landmarks.astype(np.float64)
    pts = pts - pts[:, RIGID].mean(1, keepdims=True)
    F = len(pts)
    w = pts.transpose(0, 2, 1).reshape(2 * F, 68)
    u, s, vt = np.linalg.svd(w[:, RIGID], full_matrices=False)
    M = u[:, :3] * np.sqrt(s[:3])
    # metric constraints: rows i, j of each camera orthogonal with equal norm
    def row(a, b):
        return np.array([a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[0] * b[2] + a[2] * b[0],
                         a[1] * b[1], a[1] * b[2] + a[2] * b[1], a[2] * b[2]])
    A, rhs = [], []
    for f in range(F):
        i, j = M[2 * f], M[2 * f + 1]
        A += [row(i, i) - row(j, j), row(i, j)]
        rhs += [0.0, 0.0]
    A.append(row(M[0], M[0]))
    rhs.append(1.0)
    q = np.linalg.lstsq(np.array(A), np.array(rhs), rcond=None)[0]
    L = np.array([[q[0], q[1], q[2]], [q[1], q[3], q[4]], [q[2], q[4], q[5]]])
    ev, evec = np.linalg.eigh(L)
    Q = evec @ np.diag(np.sqrt(np.clip(ev, 1e-9, None)))
    Mq = M @ Q
    shape = np.linalg.lstsq(Mq, w, rcond=None)[0].T          # all 68 points (68, 3)
    return _to_canonical(shape)


def _to_canonical(X: np.ndarray, allow_reflection: bool = True) -> np.ndarray:
    """Express a (68, 3) shape in the canonical face frame (see module doc), IOD = IOD_MM.

    ``allow_reflection``: a shape whose chin comes out above the nose bridge is reflected back
    (right for a factorisation, which is defined only up to a mirror image). A shape refined
    against perspective images is not: reflecting it would make it inconsistent with every
    pose it was fitted to, so with False it is only rotated and scaled (see ``_plausible``).
    """
    X = np.asarray(X, np.float64)
    plane = X[[36, 39, 42, 45, 31, 35, 48, 54]]
    c = plane.mean(0)
    z = np.linalg.svd(plane - c)[2][2]
    if np.dot(X[30] - c, z) > 0:         # the nose tip must point toward the viewer (−z)
        z = -z
    x = X[LEO] - X[REO]
    x = x - np.dot(x, z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    origin = (X[REO] + X[LEO]) / 2
    out = (X - origin) @ R.T
    if allow_reflection and out[8, 1] < out[27, 1]:   # chin above the nose bridge: a mirror image
        out[:, 1] *= -1                  # (factorisation sign ambiguity) — reflect it back
    return out * (IOD_MM / np.linalg.norm(out[LEO] - out[REO]))


def _plausible(X: np.ndarray) -> bool:
    """Is a canonical (68, 3) shape a face at all (finite, head-sized, nose in front, chin below)?

    Bundle adjustment of a short, nearly rigid clip can run off along its unobservable depth
    direction (points 10⁶ mm deep, a depth-inverted or mirrored face) while its own RMS stays low;
    a factorisation of a face that turns little can come out stretched in depth (twice a head's
    depth: the render-back then smears the nose into the upper lip), so the rigid points may span
    at most ``MAX_DEPTH_MM``.
    The lips are fitted after the rigid points with the poses fixed, and their motion (the mouth
    opens as the head nods) can pass for depth: a fit whose lips stand in front of the nose tip, or
    whose upper and lower lip are ``MAX_LIP_STEP_MM`` or more apart in depth, is no face either (the
    surface would fold at the mouth and render the lips over the mouth's interior).
    """
    if not np.all(np.isfinite(X)) or np.abs(X).max() > 300.0:
        return False
    z = X[:, 2]
    return bool(np.ptp(z[RIGID]) < MAX_DEPTH_MM and z[30] < min(z[LEO], z[REO]) and z[[0, 16]].mean() > z[30]
                and X[8, 1] > X[30, 1] > X[27, 1]
                and z[30] < z[MOUTH].min() and np.ptp(z[LIP_MIDLINE]) < MAX_LIP_STEP_MM)


def frame_errors(shape: np.ndarray, observations: list[np.ndarray], cameras: list[np.ndarray]) -> np.ndarray:
    """Per-frame RMS reprojection error (px) of the rigid landmarks, each pose solved globally by PnP."""
    return np.array([solve_pose(shape[RIGID], obs[RIGID], K)[2] for obs, K in zip(observations, cameras)])


def refine_with_prior(start: np.ndarray, observations: list[np.ndarray], cameras: list[np.ndarray],
                      weight: float = 2.0, iterations: int = 30, tol: float = 1e-4) -> np.ndarray:
    """Bundle adjustment regularised towards ``start`` (resection–intersection), → (68, 3) canonical.

    Minimises Σ_f Σ_k |π_f(X_k) − u_fk|² + weight · s² Σ_k |X_k − start_k|², with s the face's
    mean scale in px/mm, i.e. the start counts as ``weight`` frontal views of every point. Poses
    (PnP on the rigid points) and points (one Gauss–Newton step each, all 68 independent given
    the poses) alternate. Depth a clip with little head rotation cannot observe stays at the
    start; what it does observe (the 2D shape, rotation parallax) is fitted. The prior also fixes
    the gauge, so nothing can drift to infinity. Deterministic (no randomness, fixed order).
    """
    S0 = np.asarray(start, np.float64)
    obs = np.asarray(observations, np.float64)                       # (F, 68, 2)
    Ks = np.asarray(cameras, np.float64)                              # (F, 3, 3)
    scale = float(np.mean(np.linalg.norm(obs[:, LEO] - obs[:, REO], axis=1))) / np.linalg.norm(S0[LEO] - S0[REO])
    lam = weight * scale ** 2
    X = S0.copy()
    poses = [None] * len(obs)
    prev = np.inf
    for _ in range(iterations):
        sq = 0.0
        for f in range(len(obs)):
            r, t, e = solve_pose(X[RIGID], obs[f, RIGID], Ks[f], poses[f])
            if poses[f] is not None and not np.isfinite(e):
                r, t, e = solve_pose(X[RIGID], obs[f, RIGID], Ks[f])
            poses[f] = (r, t)
            sq += e ** 2
        rms = np.sqrt(sq / len(obs))
        if prev - rms < tol * prev:
            break
        prev = rms
        Rs = np.stack([rotation(r) for r, _ in poses])                  # (F, 3, 3)
        ts = np.stack([t for _, t in poses])                             # (F, 3)
        P = np.einsum("fij,kj->fki", Rs, X) + ts[:, None]               # (F, 68, 3) camera coords
        zc = P[..., 2:3]
        fx, fy = Ks[:, 0, 0][:, None], Ks[:, 1, 1][:, None]
        uv = np.stack([fx * P[..., 0] / zc[..., 0] + Ks[:, 0, 2][:, None],
                       fy * P[..., 1] / zc[..., 0] + Ks[:, 1, 2][:, None]], -1)
        res = obs - uv                                                   # (F, 68, 2)
        dproj = np.zeros(P.shape[:2] + (2, 3))                           # d uv / d P
        dproj[..., 0, 0] = fx / zc[..., 0]
        dproj[..., 0, 2] = -fx * P[..., 0] / zc[..., 0] ** 2
        dproj[..., 1, 1] = fy / zc[..., 0]
        dproj[..., 1, 2] = -fy * P[..., 1] / zc[..., 0] ** 2
        J = np.einsum("fkab,fbc->fkac", dproj, Rs)                       # (F, 68, 2, 3) d uv / d X
        H = np.einsum("fkai,fkaj->kij", J, J) + lam * np.eye(3)
        g = np.einsum("fkai,fka->ki", J, res) + lam * (S0 - X)
        X = X + np.linalg.solve(H, g[..., None])[..., 0]
    return _to_canonical(X, allow_reflection=False)


def bundle_adjust(shape: np.ndarray, observations: list[np.ndarray], cameras: list[np.ndarray],
                  max_iterations: int = 100, fallback: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """Refine ``shape`` with pycolmap bundle adjustment over frames.

    Parameters
    ----------
    shape : (68, 3) start shape (mm, canonical frame).
    observations : list of (68, 2) landmark pixels, one per frame.
    cameras : list of (3, 3) intrinsics, one per frame (frames of one video share values).
    fallback : (68, 3) canonical shape kept when no fit is a face (``_plausible``), e.g. the
        person's mean 2D shape with the anthropometric depth prior; None keeps ``shape``.

    Returns
    -------
    shape (68, 3) refined and re-canonicalised; RMS reprojection error of the rigid landmarks
    before and after (px).
    """
    import pycolmap

    rec = pycolmap.Reconstruction()
    cam_ids: dict[tuple, int] = {}
    poses = []
    for f, (obs, K) in enumerate(zip(observations, cameras)):
        key = (K[0, 0], K[0, 2], K[1, 2])
        if key not in cam_ids:
            cam = pycolmap.Camera(model="PINHOLE", width=int(round(2 * K[0, 2])), height=int(round(2 * K[1, 2])),
                                  params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], camera_id=len(cam_ids) + 1)
            rec.add_camera_with_trivial_rig(cam)
            cam_ids[key] = cam.camera_id
        rvec, tvec, _ = solve_pose(shape[RIGID], obs[RIGID], K)
        poses.append((rvec, tvec))
        img = pycolmap.Image(name=f"f{f}", keypoints=obs.astype(np.float64), camera_id=cam_ids[key], image_id=f + 1)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(rotation(rvec)), tvec)
        rec.add_image_with_trivial_frame(img, pose)
    pids = {}
    for k in range(68):
        track = pycolmap.Track()
        for f in range(len(observations)):
            track.add_element(f + 1, k)
        pids[k] = rec.add_point3D(shape[k], track)
    before = _rms(rec, pids, observations, cameras)

    def solve(variable_points, poses_free):
        cfg = pycolmap.BundleAdjustmentConfig()
        for f in range(len(observations)):
            cfg.add_image(f + 1)
            if not poses_free:
                cfg.set_constant_rig_from_world_pose(f + 1)
        for cid in cam_ids.values():
            cfg.set_constant_cam_intrinsics(cid)
        for k in range(68):
            if k in variable_points:
                cfg.add_variable_point(pids[k])
            else:
                cfg.add_constant_point(pids[k])
        if poses_free:
            cfg.fix_gauge(pycolmap.BundleAdjustmentGauge.THREE_POINTS)
        opts = pycolmap.BundleAdjustmentOptions()
        opts.refine_focal_length = False
        opts.refine_principal_point = False
        opts.refine_extra_params = False
        opts.print_summary = False
        opts.ceres.solver_options.max_num_iterations = max_iterations
        opts.ceres.solver_options.num_threads = 1      # one summation order: the store is byte-reproducible
        opts.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
        pycolmap.create_default_bundle_adjuster(opts, cfg, rec).solve()

    solve(set(RIGID.tolist()), poses_free=True)
    solve(set(range(68)) - set(RIGID.tolist()), poses_free=False)
    after = _rms(rec, pids, observations, cameras)
    refined = np.array([rec.point3D(pids[k]).xyz for k in range(68)])
    return _select(shape, _to_canonical(refined, allow_reflection=False), before, after, observations, cameras,
                   fallback)


def _select(start, refined, before, after, observations, cameras, fallback=None):
    """Keep the best of three fits by the per-frame PnP error they give (the way they are used).

    Candidates, in order of preference on a tie: the free bundle adjustment ``refined`` (canonical
    frame, rotated only), its depth flip (a depth-inverted fit reflected back: under the nearly
    affine view of a face it fits as well, with other poses), a bundle adjustment regularised
    towards the start (``refine_with_prior``), the start itself. On a short clip with little head
    rotation depth is unobservable and the free fit can leave the face altogether (points metres
    deep, nose behind the eyes: ``_plausible``) while its own joint RMS looks fine.
    """
    cands = [("free", refined, after)]
    flipped = _to_canonical(refined)       # depth-inverted fit reflected back (Necker reversal)
    if not np.allclose(flipped, refined):
        cands.append(("free, depth-flipped", flipped, None))
    cands += [("regularised", refine_with_prior(start, observations, cameras), None), ("start", start, None)]
    best = None
    for name, X, rms in cands:
        if not _plausible(X):
            log.info("bundle adjustment candidate %s: not a face (rejected)", name)
            continue
        errs = frame_errors(X, observations, cameras)
        med = float(np.median(errs))
        log.info("bundle adjustment candidate %s: per-frame PnP RMS median %.2f px", name, med)
        if best is None or med < best[0]:
            best = (med, name, X, float(np.sqrt(np.mean(errs ** 2))) if rms is None else rms)
    if best is None:                       # nothing face-like: the prior if given, else the start as it was
        if fallback is not None:
            log.warning("3D model: no fit is a face: the depth prior on the person's mean shape is kept")
            errs = frame_errors(fallback, observations, cameras)
            return np.asarray(fallback, np.float64), before, float(np.sqrt(np.mean(errs ** 2)))
        return start, before, after
    if best[1] != "free":
        log.info("3D model: %s fit kept (free bundle adjustment: %s)", best[1],
                 "not a face" if not _plausible(refined) else "higher per-frame error")
    return best[2], before, best[3]


def _rms(rec, pids, observations, cameras) -> float:
    errs = []
    for f, (obs, K) in enumerate(zip(observations, cameras)):
        T = rec.image(f + 1).cam_from_world().matrix()
        X = np.array([rec.point3D(pids[k]).xyz for k in range(68)])
        cam = X @ T[:, :3].T + T[:, 3]
        uv = cam @ K.T
        errs.append(np.sum((uv[:, :2] / uv[:, 2:3] - obs)[RIGID] ** 2, axis=1))
    return float(np.sqrt(np.mean(errs)))
