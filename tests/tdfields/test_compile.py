import torch

import tdfields


def test_torch_compile_matches_eager_values_and_gradients():
    torch.manual_seed(0)
    f = tdfields.build({"kind": "multires", "levels": [
        {"kind": "six_axis", "aabb": [[0, 1]] * 3, "cell_size": 0.25, "channels": 4, "rank": 2},
        {"kind": "cp", "aabb": [[0, 1]] * 3, "cell_size": 0.1, "channels": 4, "rank": 2}]})
    compiled = torch.compile(f)
    x = torch.rand(64, 3, requires_grad=True)
    y_c = compiled(x)
    (gx_c,) = torch.autograd.grad(y_c.square().sum(), x)
    y_e = f(x)
    (gx_e,) = torch.autograd.grad(y_e.square().sum(), x)
    torch.testing.assert_close(y_c, y_e)
    torch.testing.assert_close(gx_c, gx_e)
