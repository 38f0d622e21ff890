"""Parameter and memory report of every field inside any ``nn.Module``."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from torch import nn

from tdfields.field import Field


@dataclass
class FieldRow:
    """One leaf field: qualified module name, kind, grid, rank, channels, parameters, bytes, growth."""

    name: str
    kind: str
    grid_shape: tuple[int, int, int]
    rank: int | None
    channels: int
    parameters: int
    bytes: int
    complexity: str


@dataclass
class Report:
    """What :func:`report` returns. ``str(report)`` is a table; :meth:`as_dict` is JSON-ready."""

    rows: list[FieldRow]
    total_parameters: int
    total_bytes: int
    parameter_counts: dict[str, int] = field(repr=False, default_factory=dict)

    @property
    def field_parameters(self) -> int:
        """Parameters held by the fields (the rows)."""
        return sum(r.parameters for r in self.rows)

    @property
    def other_parameters(self) -> int:
        """Parameters outside any field (decoders, learnable scalars, ...)."""
        return self.total_parameters - self.field_parameters

    def parameters_under(self, prefix: str) -> int:
        """Sum of parameters whose qualified name is ``prefix`` or starts with ``prefix + '.'``."""
        return sum(n for name, n in self.parameter_counts.items() if name == prefix or name.startswith(prefix + "."))

    def as_dict(self) -> dict:
        """``{"fields": [...rows...], "field_parameters", "other_parameters", "total_parameters", "total_bytes"}``."""
        return {"fields": [asdict(r) for r in self.rows], "field_parameters": self.field_parameters,
                "other_parameters": self.other_parameters, "total_parameters": self.total_parameters,
                "total_bytes": self.total_bytes}

    def __str__(self) -> str:
        header = ("field", "kind", "grid (nx,ny,nz)", "rank", "C", "parameters", "MiB", "growth")
        body = [(r.name or "(root)", r.kind, "x".join(map(str, r.grid_shape)), "-" if r.rank is None else str(r.rank),
                 str(r.channels), f"{r.parameters:,}", f"{r.bytes / 2**20:.2f}", r.complexity) for r in self.rows]
        body.append(("fields total", "", "", "", "", f"{self.field_parameters:,}", "", ""))
        body.append(("other (decoders, ...)", "", "", "", "", f"{self.other_parameters:,}", "", ""))
        body.append(("total", "", "", "", "", f"{self.total_parameters:,}", f"{self.total_bytes / 2**20:.2f}", ""))
        widths = [max(len(row[i]) for row in [header, *body]) for i in range(len(header))]
        right = {3, 4, 5, 6}

        def fmt(row):
            return "  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths)))

        rule = "  ".join("-" * w for w in widths)
        return "\n".join([fmt(header), rule, *map(fmt, body[:-3]), rule, *map(fmt, body[-3:])])


def report(module: nn.Module) -> Report:
    """List every :class:`tdfields.Field` inside ``module`` (at any depth) with its size and growth.

    Args:
        module: any ``nn.Module`` (a field, a :class:`~tdfields.Hybrid`, a whole SLAM model, ...).

    Returns:
        :class:`Report`; totals cover all of ``module``'s parameters, fields or not.
    """
    rows = [FieldRow(name, m.kind, tuple(m.grid_shape), m.rank, m.channels, m.num_parameters(), m.memory_bytes(),
                     m.complexity)
            for name, m in module.named_modules() if isinstance(m, Field)]
    counts = {name: p.numel() for name, p in module.named_parameters()}
    total_bytes = sum(p.numel() * p.element_size() for p in module.parameters())
    return Report(rows, sum(counts.values()), total_bytes, counts)
