import torch

from slam.optim import adam


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
