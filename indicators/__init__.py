"""Indicators: decision points, t_f / t_nf / dv_nb, correlations and per-driver OLS fits."""
