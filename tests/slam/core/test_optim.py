import torch

from slam.core.optim import FusedAdam, adam


def test_fused_on_cpu_and_same_steps_as_the_default_adam():
    torch.manual_seed(0)
    a = [torch.nn.Parameter(torch.randn(50)), torch.nn.Parameter(torch.randn(()))]
    b = [torch.nn.Parameter(p.detach().clone()) for p in a]
    opt_a = adam([{"params": a[:1], "lr": 1e-2}, {"params": a[1:], "lr": 1e-3}], betas=(0.5, 0.999))
    opt_b = torch.optim.Adam([{"params": b[:1], "lr": 1e-2}, {"params": b[1:], "lr": 1e-3}], betas=(0.5, 0.999))
    assert isinstance(opt_a, FusedAdam) and not opt_b.defaults.get("fused")
    assert adam([{"params": a[:1], "lr": 1e-2}], reference=True).defaults["fused"] is True
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


def test_fused_adam_is_torch_fused_adam_bit_for_bit():
    """FusedAdam against torch.optim.Adam(fused=True), as the mapper uses them: two groups at their own rates, two
    dtypes in one group, a parameter with no gradient on some steps (no step, no state), zero_grad(set_to_none), and
    moments handed over from one to the other midway (carried moments: torch's state dict entries, loaded into the
    other by parameter). Parameters and every state tensor equal bit for bit."""
    torch.manual_seed(0)
    start = [torch.randn(40), torch.randn(6, 5, dtype=torch.float64), torch.randn(()), torch.randn(3, 2)]

    def make(cls, **kw):
        ps = [torch.nn.Parameter(t.clone()) for t in start]
        return ps, cls([{"params": ps[:2], "lr": 1e-2}, {"params": ps[2:], "lr": 3e-3}], **kw)

    ours, opt_a = make(FusedAdam)
    ref, opt_b = make(torch.optim.Adam, fused=True)
    g = torch.Generator().manual_seed(1)
    for step in range(12):
        if step == 6:  # the moments change hands, as MapMoments carries them between calls
            state_a = {i: {k: v.clone() for k, v in opt_a.state[p].items()} for i, p in enumerate(ours)
                       if p in opt_a.state}
            state_b = {i: {k: v.clone() for k, v in opt_b.state[p].items()} for i, p in enumerate(ref)
                       if p in opt_b.state}
            ours2, opt_a = make(FusedAdam)
            ref2, opt_b = make(torch.optim.Adam, fused=True)
            for new, old, opt, state in ((ours2, ours, opt_a, state_b), (ref2, ref, opt_b, state_a)):
                for i, (n, o) in enumerate(zip(new, old)):
                    n.data.copy_(o.data)
                    if i in state:
                        opt.state[n] = {k: v.clone() for k, v in state[i].items()}
            ours, ref = ours2, ref2
        noise = [torch.randn(t.shape, generator=g, dtype=t.dtype) for t in start]
        for ps, opt in ((ours, opt_a), (ref, opt_b)):
            opt.zero_grad(set_to_none=True)
            loss = sum(((p - n) ** 3).abs().sum() for p, n in zip(ps[:3], noise))
            if step % 3 == 0:  # the last parameter gets a gradient only on some steps
                loss = loss + (ps[3] * noise[3]).sum()
            loss.backward()
            opt.step()
    for p, q in zip(ours, ref):
        assert torch.equal(p, q)
        assert (p in opt_a.state) == (q in opt_b.state)
        if p in opt_a.state:
            for k in ("step", "exp_avg", "exp_avg_sq"):
                assert torch.equal(opt_a.state[p][k], opt_b.state[q][k]), k
            assert opt_a.state[p]["step"].dtype == opt_b.state[q]["step"].dtype == torch.float32
    assert float(opt_a.state[ours[3]]["step"]) == 4.0  # steps 0, 3, 6 and 9
