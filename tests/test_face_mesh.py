"""The dense 3D head: bi-Laplacian deformation, the head mesh and its mouth cut, the textured EGL render,
the OBJ + PC2 export (``pipeline.face.bilaplacian``, ``head_mesh``, ``face_mesh``, ``mesh_export``)."""
import numpy as np
import pytest

from pipeline.face import face_mesh
from pipeline.face import head_mesh as hm
from pipeline.face.bilaplacian import BiLaplacian, graph_laplacian
from pipeline.face.head_texture import HeadWindow, pick_still_frames
from pipeline.params import Params
from stages.frontalize.frontalize import build_surface

INNER_UPPER, INNER_LOWER = [61, 62, 63], [65, 66, 67]


@pytest.fixture(scope="module")
def head(face3d):
    """(surface, window, landmarks (68, 2) mm, rest HeadMesh) of a real face's 68-point model."""
    surface = hm.smooth_surface(build_surface(face3d, Params().frontalize)[0])
    window = HeadWindow.covering(1.0)
    lm = face3d[:, :2].astype(np.float64)
    lm[[67, 66, 65]] = lm[[61, 62, 63]] + [0.0, 0.5]     # the photo smiles with teeth: shut its mouth
    return surface, window, lm, hm.head_mesh(surface, window, lm, 2.0)


def grid(n=21):
    xs = np.arange(n, dtype=float)
    gx, gy = np.meshgrid(xs, xs)
    w = n
    r, c = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (r * w + c).ravel()
    tris = np.concatenate([np.column_stack([a, a + w, a + 1]), np.column_stack([a + 1, a + w, a + w + 1])])
    return np.column_stack([gx.ravel(), gy.ravel()]), tris


def test_laplacian_rows_sum_to_zero_and_count_each_edge_once():
    v, t = grid(5)
    L = graph_laplacian(len(v), t).toarray()
    assert np.allclose(L.sum(1), 0) and np.allclose(np.diag(L), 1)
    assert np.isclose(L[0, 1], -1 / 2)             # corner (0, 0): 2 neighbours (the diagonals run the other way)
    assert np.isclose(L[6, 7], -1 / 6)             # an inner vertex: 6


def test_bilaplacian_carries_handles_holds_anchors_and_spreads_smoothly():
    v, t = grid(21)
    centre = 10 * 21 + 10
    anchors = np.flatnonzero((v[:, 0] == 0) | (v[:, 0] == 20) | (v[:, 1] == 0) | (v[:, 1] == 20))
    deform = BiLaplacian(len(v), t, np.array([centre]), anchors)
    d = deform(np.array([[[0.0, 0.0]], [[0.0, 3.0]]]))
    assert np.allclose(d[0], 0)                                        # no motion → no displacement
    assert abs(d[1, centre, 1] - 3.0) < 0.1 and np.abs(d[1, anchors]).max() < 0.05
    dy = d[1, :, 1].reshape(21, 21)[10]                                # along the row through the handle
    assert np.all(np.diff(dy[:11]) >= -1e-9) and np.all(np.diff(dy[10:]) <= 1e-9)    # one smooth bump
    assert 0.3 < dy[5] / dy[10] < 0.95                                 # spread, neither rigid nor a spike


def test_head_mesh_is_dense_textured_and_faces_the_camera(head):
    surface, window, lm, mesh = head
    v, t, uv = mesh.skin.vertices, mesh.skin.triangles, mesh.skin.uv
    assert len(v) >= 4000 and t.min() == 0 and t.max() == len(v) - 1
    assert (uv >= 0).all() and (uv <= 1).all()
    assert np.allclose(v[:, 2], surface.z(v[:, 0], v[:, 1]))
    a, b = v[t[:, 1], :2] - v[t[:, 0], :2], v[t[:, 2], :2] - v[t[:, 0], :2]
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    assert (cross < 0).all()           # one winding, normals towards the camera (−z); no folded triangle
    # the whole face: eyes, brows and chin are covered
    for p in lm[[8, 19, 24, 36, 45, 30]]:
        assert np.linalg.norm(v[:, :2] - p, axis=1).min() < 2.0


def test_the_mouth_cut_separates_the_lips_and_no_triangle_bridges_it(head):
    _, _, lm, mesh = head
    side = mesh.side
    t = mesh.skin.triangles
    assert not ((side[t] < 0).any(1) & (side[t] > 0).any(1)).any()
    handles = hm.handle_vertices(mesh, lm[INNER_UPPER + INNER_LOWER], INNER_UPPER + INNER_LOWER)
    assert (side[handles[:3]] < 0).all() and (side[handles[3:]] > 0).all()
    assert np.linalg.norm(lm[62] - lm[66]) < 3.0      # a shut mouth: the handles nearly coincide ...


def test_opening_a_shut_mouth_parts_the_lips_without_dragging_the_upper_face(head):
    surface, _, lm, mesh = head
    ids = list(range(48, 68))
    moved = lm[ids].copy()
    lower = [ids.index(i) for i in range(55, 60)] + [ids.index(i) for i in INNER_LOWER]
    moved[lower, 1] += 10.0                                          # the lower lip drops 10 mm
    motion = face_mesh.animate(mesh, surface, lm, ids, np.stack([lm[ids], moved]))
    assert np.allclose(motion.skin[0], mesh.skin.vertices, atol=1e-6)
    h = hm.handle_vertices(mesh, lm[ids], ids)
    dy = motion.skin[1, :, 1] - mesh.skin.vertices[:, 1]
    assert (dy[h[[ids.index(i) for i in INNER_LOWER]]] > 9).all()     # ... and still part by the full 10 mm
    assert (np.abs(dy[h[[ids.index(i) for i in INNER_UPPER]]]) < 1).all()
    eyes = np.linalg.norm(mesh.skin.vertices[:, :2] - lm[[36, 45]].mean(0), axis=1) < 40
    assert np.abs(dy[eyes]).max() < 0.5
    assert (motion.lower_teeth[1, :, 1] - mesh.lower_teeth.vertices[:, 1] > 5).all()    # the jaw's teeth follow
    z = surface.z(motion.lower_teeth[1, :, 0], motion.lower_teeth[1, :, 1])
    assert np.allclose(motion.lower_teeth[1, :, 2] - z, hm.TEETH_DEPTH_MM)                # behind the skin


def test_still_frames_face_the_camera_with_the_mouth_shut():
    rng = np.random.default_rng(0)
    F = 200
    rvecs = rng.normal(0, 0.1, (F, 3))
    lms = np.zeros((F, 68, 2))
    lms[:, 66, 1] = rng.uniform(0, 10, F)
    pick = pick_still_frames(rvecs, lms, 20)
    turn, opening = np.linalg.norm(rvecs, axis=1), lms[:, 66, 1]
    assert 0 < len(pick) <= 20 and np.all(np.diff(pick) > 0)
    assert turn[pick].max() <= np.quantile(turn, 0.4) and opening[pick].max() <= np.quantile(opening, 0.3)


def test_textured_render_is_upright_and_an_open_mouth_shows_the_cavity(head, monkeypatch):
    pytest.importorskip("pyvista")
    monkeypatch.setenv("OFF_SCREEN", "True")
    surface, window, lm, mesh = head
    tex = np.zeros((window.height, window.width, 3), np.uint8)
    tex[: window.height // 2] = (200, 60, 60)            # forehead half red, chin half blue: catches a flipped v
    tex[window.height // 2:] = (60, 60, 200)
    ids = list(range(48, 68))
    moved = lm[ids].copy()
    moved[[ids.index(i) for i in list(range(55, 60)) + INNER_LOWER], 1] += 12.0
    motion = face_mesh.animate(mesh, surface, lm, ids, np.stack([lm[ids], moved]))
    r = face_mesh.HeadRenderer(mesh, tex, 160)
    try:
        shut, opened = r.render(motion, 0).astype(float), r.render(motion, 1).astype(float)
    finally:
        r.close()
    assert shut.shape == (160, 320, 3)
    front = shut[:, :160]
    top, bottom = front[30:60, 60:100].mean((0, 1)), front[110:140, 60:100].mean((0, 1))
    assert top[0] > 1.5 * top[2] and bottom[2] > 1.5 * bottom[0]      # red above, blue below, lit
    assert shut[:, 160:].sum() > 0.3 * shut[:, :160].sum()            # the three-quarter view is drawn too
    import cv2
    face = cv2.erode((front.sum(-1) > 60).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0   # inside the silhouette
    dark_shut = face & (front.sum(-1) < 100)
    dark_open = face & (opened[:, :160].sum(-1) < 100)                 # the cavity seen through the lips
    ys = np.nonzero(dark_open)[0]
    assert dark_shut.sum() < 10 and dark_open.sum() > 60
    assert 80 < np.median(ys) < 140                                     # low in the face: the mouth


def test_export_writes_obj_texture_and_a_point_cache_that_reads_back(head, tmp_path):
    from pipeline.face import mesh_export
    surface, window, lm, mesh = head
    frames = np.stack([mesh.skin.vertices, mesh.skin.vertices + [0, 1, 0]])
    tex = np.full((window.height, window.width, 3), 128, np.uint8)
    paths = mesh_export.write_animated_mesh(tmp_path / "head", mesh.skin, frames, tex, 25.0)
    assert [p.suffix for p in paths] == [".obj", ".mtl", ".png", ".pc2"] and all(p.is_file() for p in paths)
    lines = (tmp_path / "head.obj").read_text().splitlines()
    assert sum(x.startswith("v ") for x in lines) == len(mesh.skin.vertices)
    assert sum(x.startswith("vt ") for x in lines) == len(mesh.skin.vertices)
    assert sum(x.startswith("f ") for x in lines) == len(mesh.skin.triangles)
    cache = mesh_export.read_pc2(tmp_path / "head.pc2")
    assert cache.shape == frames.shape
    assert np.allclose(cache, frames * [1, -1, -1], atol=1e-3)        # y up, z to the viewer
    assert not list(tmp_path.glob("*.tmp*"))


def test_a_model_folder_without_a_3d_face_is_refused_in_one_line(tmp_path):
    from pipeline.models.model_folder import ModelError
    from stages.render_mesh.render_mesh import speaker_head
    np.savez(tmp_path / "speaker.npz", shape3d=np.zeros((68, 3)), identity=np.zeros(128), identity_spread=np.zeros(3))
    with pytest.raises(ModelError, match="no 3D face") as e:
        speaker_head(str(tmp_path))
    assert "\n" not in str(e.value) and str(tmp_path) in str(e.value)


def test_no_pale_line_of_teeth_while_the_predicted_inner_lips_touch(head, monkeypatch):
    """Front view, uniform grey skin: with the inner lips 1 mm apart the sliver between them shows no bright
    (teeth-coloured) pixel; 5 mm apart, the teeth show."""
    pytest.importorskip("pyvista")
    monkeypatch.setenv("OFF_SCREEN", "True")
    surface, window, lm, mesh = head
    ids = list(range(48, 68))
    lower = [ids.index(i) for i in list(range(55, 60)) + INNER_LOWER]
    moved = np.repeat(lm[ids][None], 3, 0)
    gap = (lm[INNER_LOWER, 1] - lm[INNER_UPPER, 1]).mean()
    moved[1, lower, 1] += 1.0 - gap                                   # touching: 1 mm apart
    moved[2, lower, 1] += 5.0 - gap                                   # parted: 5 mm
    motion = face_mesh.animate(mesh, surface, lm, ids, moved)
    assert list(face_mesh.teeth_hidden(ids, moved)) == [1.0, 1.0, 0.0]
    r = face_mesh.HeadRenderer(mesh, np.full((window.height, window.width, 3), 150, np.uint8), 320)
    try:
        r.render(motion, 0)
        touching, parted = (r.render(motion, t)[:, :320].astype(int).sum(-1) for t in (1, 2))
    finally:
        r.close()
    bright = 500                                                       # lit grey skin sums to < 480 here
    assert (touching > bright).sum() == 0
    assert (parted > bright).sum() > 50
    dark = (touching < 60)[100:, 60:260]                              # the sliver is the dark cavity instead
    assert dark.sum() > 20


def test_the_outline_runs_inside_the_jaw_contours_sides_but_keeps_the_chin(head):
    _, _, lm, mesh = head
    v = mesh.skin.vertices[:, :2]
    for j, side in ((2, -1), (3, -1), (13, 1), (14, 1)):
        row = v[np.abs(v[:, 1] - lm[j, 1]) < 1.5]
        edge = row[:, 0].min() if side < 0 else row[:, 0].max()
        assert side * (lm[j, 0] - edge) > 1.5, (j, edge, lm[j])        # a few mm in from the tracked contour
    assert np.linalg.norm(v - lm[8], axis=1).min() < 2.0                 # the chin still covered


def fold_texture(window, lm, sides):
    """Plain skin with a dark smile line 2.5 mm wide, 5 mm outside the nose wing → mouth corner, on ``sides`` (−1, +1)."""
    import cv2
    tex = np.full((window.height, window.width, 3), (200, 170, 150), np.uint8)
    for s in sides:
        ends = (lm[31 if s < 0 else 35] + [5.0 * s, 0.0], lm[48 if s < 0 else 54] + [5.0 * s, 3.0])
        px = [tuple(np.round((p - [window.x0, window.y0]) / window.mm_per_px).astype(int).tolist()) for p in ends]
        cv2.line(tex, px[0], px[1], (70, 50, 45), max(1, round(2.5 / window.mm_per_px)), cv2.LINE_AA)
    return tex


def test_the_three_quarter_view_draws_no_hard_streak_where_it_squeezes_the_far_cheek(head, monkeypatch):
    """A smile line on each cheek (symmetric): the front view shows both as dark as each other; the three-quarter
    view squeezes the far one (beside the nose, ∂z/∂x ≈ −1: ≈ 0.35 of its width), and it must not show there as a
    line as dark as the near one — the hard dark fold of issue 50. The front view's texture is untouched."""
    pytest.importorskip("pyvista")
    monkeypatch.setenv("OFF_SCREEN", "True")
    from pipeline.face.head_texture import turned_view_texture
    surface, window, lm, mesh = head
    skin = mesh.skin
    plain = fold_texture(window, lm, (-1, 1))
    assert np.array_equal(turned_view_texture(plain, skin.vertices, skin.triangles, skin.uv, 0.0), plain)
    motion = face_mesh.HeadMotion(skin.vertices[None], mesh.upper_teeth.vertices[None], mesh.lower_teeth.vertices[None])
    lum = []
    for sides in ((), (-1,), (1,)):
        r = face_mesh.HeadRenderer(mesh, fold_texture(window, lm, sides), 320)
        try:
            lum.append(r.render(motion, 0).astype(float).sum(-1))
        finally:
            r.close()
    far, near = lum[0] - lum[1], lum[0] - lum[2]                    # how much each line darkens the render
    assert far[:, :320].max() > 200 and near[:, :320].max() > 200     # front: both lines fully drawn
    assert abs(far[:, :320].max() - near[:, :320].max()) < 40
    assert near[:, 320:].max() > 200                                  # three-quarter: the near line still is ...
    assert far[:, 320:].max() < 0.75 * near[:, 320:].max()            # ... the squeezed far one no hard streak
