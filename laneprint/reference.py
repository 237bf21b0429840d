"""Published numbers of the reference study (Li & Liu), in SI units.

See ../shared/PAPER_NOTES.md: Table 1 gives, for the three typical drivers, the
lines `I = A * v_e + b` with `v_e` in m/s, for the indicators (t_f [s],
t_nf [s], dv_nb [m/s]).
"""

INDICATORS: tuple[str, ...] = ("t_f", "t_nf", "dv_nb")
STYLES: tuple[str, ...] = ("Defensive", "Normal", "Aggressive")

#: style -> indicator -> (A, b); `I = A * v_e[m/s] + b`.
PAPER_TABLE1: dict[str, dict[str, tuple[float, float]]] = {
    "Defensive": {"t_f": (0.45, -3.26), "t_nf": (0.24, 0.42), "dv_nb": (1.01, -9.02)},
    "Normal": {"t_f": (0.23, -0.75), "t_nf": (0.16, 1.11), "dv_nb": (0.90, -6.18)},
    "Aggressive": {"t_f": (0.14, -0.25), "t_nf": (0.12, 0.86), "dv_nb": (1.01, -9.25)},
}

#: Section speed limits of the study [km/h]; drivers may exceed them by up to 5 km/h.
SPEED_LIMITS_KPH: tuple[int, ...] = (60, 70, 80, 90)

#: A target-lane follower farther than this behind the ego has no influence [m].
FAR_FOLLOWER_M: float = 100.0


def kph_to_mps(kph: float) -> float:
    """Convert km/h to m/s."""
    return kph / 3.6
