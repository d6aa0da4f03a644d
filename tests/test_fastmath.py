"""fast_atan2 against numpy's float64 arctan2 (the bound its docstring states)."""

import numpy as np
import warp as wp

from warpscatter.runtime.device import module_options
from warpscatter.runtime.fastmath import fast_atan2

module_options()


@wp.kernel
def _atan2_kernel(y: wp.array(dtype=wp.float32), x: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.float32)):
    k = wp.tid()
    out[k] = fast_atan2(y[k], x[k])


def test_fast_atan2_within_its_bound_in_every_octant():
    rng = np.random.default_rng(5)
    y = np.concatenate([rng.normal(size=200000), [0.0, 0.0, 1.0, -1.0, 1.0, 1e-30, -3.0]]).astype(np.float32)
    x = np.concatenate([rng.normal(size=200000), [1.0, -1.0, 0.0, 0.0, 1.0, -1.0, -3.0]]).astype(np.float32)
    out = wp.empty(len(x), dtype=wp.float32)
    wp.launch(_atan2_kernel, len(x), [wp.array(y), wp.array(x), out])
    want = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    err = np.abs(out.numpy() - want)
    err = np.minimum(err, 2 * np.pi - err)  # -pi and pi are the same angle
    assert err.max() < 2.5e-6  # measured 1.9e-6
    assert out.numpy()[-7] == 0.0
