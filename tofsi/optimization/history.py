"""A design iteration's record: one row of ``history.csv``/``history.json`` and of a checkpoint.

Quantities that do not apply at an iteration -- the moved mesh's quality in a
one-way stage, the skewness bound where none is set -- are NaN in the record
and ``None`` in a row (a blank CSV cell, JSON null): no result file holds a NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, fields


@dataclass
class Iteration:
    iteration: int
    stage: int
    objective: float           # unscaled
    scaled_objective: float    # by the stage's first value
    volume: float              # solid fraction of the design region
    constraint: float          # g <= 0 feasible
    change: float              # max |gamma - gamma_previous|
    beta: float
    penalty: float
    brinkman_q: float
    time_s: float
    coupling: str = ""            # one-way stage of a two-way problem, or as the scene
    min_skewness: float = float("nan")        # of the moved fluid mesh (NaN: the mesh did not move)
    min_area_change: float = float("nan")
    max_area_change: float = float("nan")
    max_interface_gap: float = float("nan")    # max |x - u| [m] on the solid's nodes (rho >= 1/2)
    skewness_constraint: float = float("nan")  # g of design.min_skewness (NaN: not constrained here)
    fallbacks: int = 0                         # failed trial designs so far in the run
    load_steps: int = 0                        # steps of the inflow ramp this evaluation took (0: none)
    load_cutbacks: int = 0

    def row(self) -> dict:
        """The history row: NaN where a quantity does not apply (the mesh did not move, no
        skewness bound) becomes None (a blank CSV cell, JSON null); every other value is finite."""
        row = {name: getattr(self, name) for name in FIELDS}     # flat: no deep copy (asdict's)
        for key in NOT_APPLICABLE:
            if row[key] != row[key]:
                row[key] = None
        return row

    @classmethod
    def from_row(cls, row: dict) -> "Iteration":
        """The inverse of :meth:`row` (a checkpoint's history)."""
        return cls(**{k: float("nan") if v is None and k in NOT_APPLICABLE else v for k, v in row.items()})


FIELDS = tuple(f.name for f in fields(Iteration))
NOT_APPLICABLE = ("min_skewness", "min_area_change", "max_area_change", "max_interface_gap",
                  "skewness_constraint")
