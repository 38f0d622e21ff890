"""Every kind learns a sphere SDF to a stated error within a stated number of Adam steps on the CPU.

The bound and step count are what docs/tdfields.md quotes; the docs table came from
benchmarks/fit_rates.py (at f5975fa, since retired), which ran the same fit longer.
"""

import torch

import tdfields

STEPS = 200
BOUND_M = 0.02  # mean |SDF error| in metres on held-out points, sphere radius 0.6 m in a 2 m box
RANKS = {"vector_matrix": 4, "cp": 8, "six_axis": 8}


def sphere_sdf(p):
    return p.norm(dim=-1) - 0.6


def fit(kind, steps=STEPS, seed=0):
    torch.manual_seed(seed)
    spec = {"kind": kind, "aabb": [[-1, 1]] * 3, "cell_size": 0.1, "channels": 8}
    if kind in RANKS:
        spec["rank"] = RANKS[kind]
    field = tdfields.build(spec)
    dec = tdfields.MLPDecoder(8, 1, hidden=32)
    opt = torch.optim.Adam([{"params": field.parameters(), "lr": 0.02}, {"params": dec.parameters(), "lr": 0.005}])
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        x = torch.rand(4096, 3, generator=g) * 2 - 1
        loss = (dec(field(x)).squeeze(-1) - sphere_sdf(x)).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    xt = torch.rand(20000, 3, generator=torch.Generator().manual_seed(1234)) * 2 - 1
    with torch.no_grad():
        return (dec(field(xt)).squeeze(-1) - sphere_sdf(xt)).abs().mean().item()


def test_fits_sphere(kind):
    err = fit(kind)
    assert err < BOUND_M, f"{kind}: mean |error| {err:.4f} m after {STEPS} steps"


def test_untrained_is_far_off():
    """Guard: the bound above is not trivially met without training."""
    assert fit("cp", steps=0) > 5 * BOUND_M
