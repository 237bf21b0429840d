"""Indicators: decision points, the study's t_f / t_nf / dv_nb and what drivers accept (gaps,
headways, relative speeds), correlations and per-driver OLS fits (pooled and per direction).

Modules (pure functions of DataFrames; only `clustering.pipeline.analyze` touches the workspace):

- `settings`: `AnalysisSettings`, every knob of `laneprint analyze`, one comment per field.
- `decisions`: `extract_decisions(meta, ego, traffic, settings) -> (decisions, skipped)`, one
  recording at a time, vectorised over all its states. Presses are labelled 'change', the
  states every `step_s` before them 'keep' (schema `laneprint.schemas.DECISIONS` plus
  `press_index`, `lc_direction`, `lane_change_t_s`, `f_id`/`nf_id`/`nb_id` and
  `<indicator>_reason`: why a value is left out of the fits, '' when used).
- `acceptance`: gap_f, thw_f, dv_f, gap_nf, dv_nf, gap_nb, thw_nb with their statuses
  (`add_acceptance`, derived from the scene columns, so any decisions table gets them).
- `stats`: `correlate` (Pearson + Spearman per driver and indicator) and `fit_lines` (statsmodels
  OLS `I = A v_e + b` with SEs, 95 % CIs, R², n, and `cov_Ab`/`resid_sd`/`df_resid` so bands
  can be drawn from the table alone: `LineFit.from_row(row).bands(v)`); `flag` says why a
  fitted line means little (R² below `min_fit_r2`, slope interval spanning 0, few points)
  and `level` is the median of the values.
- `directions`: the same fits per direction of the lane change (left: overtaking; right:
  returning), where a side has enough presses.
- `plots`: `indicator_vs_speed`, `correlation_table` (Plotly figures).
- `synthetic`: tiny hand-checkable recordings and large in-memory decision tables (tests, benchmarks).

Which presses feed the statistics: label 'change' (cancelled presses included unless
`fit_cancelled=False`), values with status 'ok' only; 'far' followers are out unless
`fit_far_followers`; a TTC whose closing speed is below `min_closing_mps` (the driver was
following a slow leader: TTC of tens or hundreds of seconds) is out with reason 'following';
a front gap or headway whose leader pulls away faster than `max_receding_mps` (the driver is
not held by it, as on most returns to the right) is out with reason 'receding'.
The values stay in the decisions table either way.
"""
