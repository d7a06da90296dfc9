"""pipeline.video.flow: the flow of smaller copies, scaled up to the full size."""
import cv2
import numpy as np
import skimage.data

from pipeline.video.flow import flow_at_most


def test_the_flow_of_smaller_copies_is_the_full_size_shift():
    """A 512 px image and the same shifted by (8, −12) px: the flow found at 128 px, scaled up, says (8, −12)
    (a flow left at the small copies' scale would say (2, −3))."""
    a = cv2.cvtColor(cv2.resize(skimage.data.astronaut(), (512, 512), interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
    b = cv2.warpAffine(a, np.float32([[1, 0, 8], [0, 1, -12]]), (512, 512), borderMode=cv2.BORDER_REFLECT)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    f = flow_at_most(dis, a, b, 128)                 # a(p) ≈ b(p + f(p)): b is a moved by (8, −12)
    assert f.shape == (512, 512, 2) and f.dtype == np.float32
    inner = f[96:-96, 96:-96].reshape(-1, 2)
    np.testing.assert_allclose(np.median(inner, 0), [8.0, -12.0], atol=0.5)


def test_an_image_no_larger_than_the_limit_gets_the_flow_itself():
    rng = np.random.default_rng(0)
    a = cv2.GaussianBlur(rng.integers(0, 255, (96, 96), dtype=np.uint8), (0, 0), 2)
    b = np.roll(a, 2, axis=1)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    np.testing.assert_array_equal(flow_at_most(dis, a, b, 128), dis.calc(a, b, None))
