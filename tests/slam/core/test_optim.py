import torch

from slam.core.optim import adam


def test_fused_on_cpu_and_same_steps_as_the_default_adam():
    torch.manual_seed(0)
    a = [torch.nn.Parameter(torch.randn(50)), torch.nn.Parameter(torch.randn(()))]
    b = [torch.nn.Parameter(p.detach().clone()) for p in a]
    opt_a = adam([{"params": a[:1], "lr": 1e-2}, {"params": a[1:], "lr": 1e-3}], betas=(0.5, 0.999))
    opt_b = torch.optim.Adam([{"params": b[:1], "lr": 1e-2}, {"params": b[1:], "lr": 1e-3}], betas=(0.5, 0.999))
    assert opt_a.defaults["fused"] is True and not opt_b.defaults.get("fused")
    for step in range(20):
        g = torch.randn(50)
        for params, opt in ((a, opt_a), (b, opt_b)):
            opt.zero_grad()
            ((params[0] * g).sum() + params[1] ** 2 * (step + 1)).backward()
            opt.step()
    for p, q in zip(a, b):
        torch.testing.assert_close(p, q, rtol=1e-5, atol=1e-6)


def test_fused_cpu_needs_torch_2_4():
    from slam.core.optim import FUSED_CPU_MIN_TORCH, fused_devices

    assert FUSED_CPU_MIN_TORCH == (2, 4)
    assert fused_devices("2.3.1+cpu") == ("cuda",) and fused_devices("2.1.0") == ("cuda",)
    assert fused_devices("2.4.0") == ("cpu", "cuda") and fused_devices("2.13.0+cpu") == ("cpu", "cuda")
    assert fused_devices("2.10.0a0+git1234") == ("cpu", "cuda")  # not a string comparison: 2.10 > 2.4


def test_older_torch_takes_foreach_on_cpu_and_the_same_steps(monkeypatch):
    """On torch < 2.4, Adam(fused=True) raises for CPU tensors; adam() must not ask for it there."""
    real_adam = torch.optim.Adam

    class Torch23Adam(real_adam):  # what torch 2.1-2.3 does with fused=True on CPU parameters
        def __init__(self, params, *args, fused=None, **kwargs):
            if fused:
                raise RuntimeError("`fused=True` requires all the params to be floating point Tensors of "
                                   "supported devices: ['cuda', 'xpu', 'privateuseone'].")
            super().__init__(params, *args, fused=fused, **kwargs)

    monkeypatch.setattr(torch, "__version__", "2.3.1+cpu")
    monkeypatch.setattr(torch.optim, "Adam", Torch23Adam)
    torch.manual_seed(0)
    a = torch.nn.Parameter(torch.randn(30))
    b = torch.nn.Parameter(a.detach().clone())
    opt_a = adam([{"params": [a], "lr": 1e-2}], betas=(0.5, 0.999))
    opt_b = real_adam([{"params": [b], "lr": 1e-2}], betas=(0.5, 0.999), foreach=False)
    assert not opt_a.defaults["fused"] and opt_a.defaults["foreach"] is True
    for _ in range(10):
        g = torch.randn(30)
        for p, opt in ((a, opt_a), (b, opt_b)):
            opt.zero_grad()
            (p * g).sum().backward()
            opt.step()
    torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)



def test_vector_adam_takes_the_steps_of_torch_adam_with_two_groups():
    import torch

    from slam.core.optim import VectorAdam

    g = torch.Generator().manual_seed(0)
    start = torch.randn(7, generator=g, dtype=torch.float64)
    q = torch.nn.Parameter(start[:4].clone())
    t = torch.nn.Parameter(start[4:].clone())
    ref = torch.optim.Adam([{"params": [q], "lr": 0.002}, {"params": [t], "lr": 0.01}], betas=(0.5, 0.999),
                           foreach=False)
    p = start.clone().requires_grad_(True)
    ours = VectorAdam(p, torch.tensor([0.002] * 4 + [0.01] * 3, dtype=torch.float64), betas=(0.5, 0.999))
    target = torch.randn(7, generator=g, dtype=torch.float64)
    for _ in range(30):
        ref.zero_grad()
        (torch.cat((q, t)) - target).pow(3).abs().sum().backward()
        ref.step()
        ours.zero_grad()
        (p - target).pow(3).abs().sum().backward()
        ours.step()
    torch.testing.assert_close(p.detach(), torch.cat((q, t)).detach(), rtol=1e-12, atol=1e-14)
