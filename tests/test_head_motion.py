"""Blinks and head motion replayed from the person's footage (``pipeline.face.head_motion``), applied to the
head (``face_mesh.with_footage``), exported with the head's turn as a node rotation (``gltf_export``)."""
import numpy as np
import pytest

from pipeline.errors import LipsynthError
from pipeline.face import face_mesh, gltf_export
from pipeline.face import head_motion as hmo
from tests.test_face_mesh import head  # noqa: F401  (the rest head fixture)


def eyes(openness: np.ndarray) -> np.ndarray:
    """(F, 68, 2) landmarks whose eyes are 30 mm wide and ``openness`` × 10 mm tall."""
    lm = np.zeros((len(openness), 68, 2))
    for (c0, u1, u2, c1, l1, l2), x0 in zip(hmo.EYES, (-45.0, 15.0)):
        lm[:, [c0, c1], 0] = [x0, x0 + 30]
        lm[:, [u1, l1], 0], lm[:, [u2, l2], 0] = x0 + 10, x0 + 20
        lm[:, [u1, u2], 1] = -5 * openness[:, None]
        lm[:, [l1, l2], 1] = 5 * openness[:, None]
    return lm


def fake_store(path, openness, rvec, fps=25.0):
    """A frontalize store with one video: frontal landmarks with these eyes, these poses, all valid."""
    import zarr
    n = len(openness)
    g = zarr.open_group(str(path), mode="w")
    g.create_array("frontal_landmarks", data=eyes(openness).astype(np.float32))
    g.create_array("pose", data=np.concatenate([rvec, np.zeros((n, 3))], 1).astype(np.float32))
    g.create_array("pose_valid", data=np.ones(n, bool))
    g.attrs["videos"] = [{"name": "v", "first_frame": 0, "n_frames": n, "fps": fps}]
    return path


def test_the_eye_aspect_ratio_and_closure_follow_the_eyelids():
    openness = np.ones(100)
    openness[[40, 41, 42]] = [0.6, 0.3, 0.6]                          # one blink
    ear = hmo.eye_aspect(eyes(openness))
    assert ear[0] == pytest.approx(10 / 30) and ear[41] == pytest.approx(0.1)
    c = hmo.closure_of(ear)
    assert c[41] == 1.0 and c[40] > 0.5 and (np.delete(c, [40, 41, 42]) == 0).all()


def test_footage_tracks_replay_the_persons_blinks_and_turns_at_the_output_rate(tmp_path):
    n = 50
    openness = np.ones(n)
    openness[20] = 0.2
    yaw = np.radians(4) * np.sin(np.arange(n) / 5)
    store = fake_store(tmp_path / "f.zarr", openness, np.column_stack([np.zeros(n), yaw, np.zeros(n)]))
    tr = hmo.footage_tracks(store, 170, 50.0)                         # 2 × the footage's rate, 1.7 × its length
    assert tr.closure.shape == (170,) and tr.rotation.shape == (170, 3, 3)
    assert tr.closure[40] == 1.0 and tr.closure[:38].max() == 0      # the blink at 0.8 s
    assert tr.closure[150:165].max() == 1.0 and tr.closure[100:150].max() == 0     # ping-pong: it comes back
    angle = np.degrees(np.arccos(np.clip((np.trace(tr.rotation, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert 2 < angle.max() < 8.5 and np.allclose(np.linalg.det(tr.rotation), 1)
    with pytest.raises(LipsynthError, match="no footage store") as e:
        hmo.footage_tracks(tmp_path / "absent.zarr", 10, 25.0)
    assert "\n" not in str(e.value)


def test_a_blink_slides_the_upper_lid_onto_the_lower_and_leaves_the_rest(head):  # noqa: F811
    surface, _, lm, mesh = head
    xy = mesh.skin.vertices[:, :2]
    dy = hmo.blink_offsets(xy, lm)
    lo_mid = (lm[40] + lm[41]) / 2
    up_mid = (lm[37] + lm[38]) / 2
    i = np.argmin(np.linalg.norm(xy - up_mid, axis=1))                # the upper lid's middle ...
    assert xy[i, 1] + dy[i] == pytest.approx(lo_mid[1], abs=1.5)      # ... reaches the lower lid
    far = np.linalg.norm(xy - lm[[36, 45]].mean(0), axis=1) > 60
    assert (dy[far] == 0).all() and (dy >= 0).all()
    ids = list(range(48, 68))
    moved = np.repeat(lm[ids][None], 2, 0)
    motion = face_mesh.animate(mesh, surface, lm, ids, moved)
    turn = np.stack([np.eye(3), hmo.rotation_matrices(np.array([[0.0, np.radians(10), 0.0]]))[0]])
    blinked = face_mesh.with_footage(motion, mesh, surface, lm, np.array([0.0, 1.0]), turn)
    assert np.allclose(blinked.skin[0], motion.skin[0])
    assert blinked.skin[1, i, 1] > motion.skin[1, i, 1] + 2
    posed = blinked.posed(blinked.skin)
    assert np.allclose(posed[0], blinked.skin[0])
    assert np.allclose(np.linalg.norm(posed[1] - blinked.pivot, axis=1), np.linalg.norm(blinked.skin[1] - blinked.pivot,
                                                                                           axis=1))   # rigid


def test_a_turning_head_exports_as_a_node_rotation_that_validates(head, tmp_path):  # noqa: F811
    from tests.helpers.gltf_validator import validate
    surface, window, lm, mesh = head
    ids = list(range(48, 68))
    T = 20
    moved = np.repeat(lm[ids][None], T, 0)
    moved[:, [ids.index(i) for i in (65, 66, 67)], 1] += np.linspace(0, 6, T)[:, None]
    yaw = np.column_stack([np.zeros(T), np.radians(np.linspace(-8, 8, T)), np.zeros(T)])
    motion = face_mesh.with_footage(face_mesh.animate(mesh, surface, lm, ids, moved), mesh, surface, lm,
                                    np.linspace(0, 1, T), hmo.rotation_matrices(yaw))
    tex = np.full((window.height, window.width, 3), 128, np.uint8)
    path = tmp_path / "turn.glb"
    gltf_export.write_glb(path, mesh, motion, tex, 25.0)
    import pygltflib
    g = pygltflib.GLTF2.load(str(path))
    paths = sorted(c.target.path for c in g.animations[0].channels)
    assert paths == ["rotation", "weights"] and g.nodes[0].children == [1, 2]
    issues = validate(path)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
