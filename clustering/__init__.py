"""Clustering: drivers into styles, typical drivers and reference lines.

- `features`: per driver, a robust line (Huber on log scale for times and gaps by default) of
  each of `feature_indicators` evaluated at 60/70/80/90 km/h.
- `selection`: which indicators the styles are read by (`--features`): each candidate set
  ('ttc', 'acceptance', 'all') is clustered and scored by silhouette x bootstrap stability;
  'auto' takes the best. The study's TTCs stay available by name ('ttc', 'paper').
- `styles`: `StyleClusterer` (scikit-learn-like): robust standardisation, median imputation
  of missing features, k-means (k fixed or chosen by silhouette/BIC), clusters ordered and
  named by defensiveness (larger TTCs, headways and gaps at the decision = more defensive),
  mixture posterior.
- `confidence`: bootstrap stability of each assignment (the `confidence` column when computed).
- `pipeline`: `analyze_tables(decisions, settings)` (pure: correlations, fits, styles,
  reference lines, skipped) and `analyze(workspace, settings, progress)` (reads every
  recording, writes the `analysis/` stage in one swap, returns the JSON-ready report).
- `plots`: `cluster_scatter`, `reference_lines` (Plotly figures).
- `cli`: `laneprint analyze`.

Tables in `analysis/`: decisions, correlations, fits, fits_by_direction, feature_sets, styles,
reference_lines (scope 'style' with kinds 'typical', 'pooled', 'paper'; scope 'driver' with
kind 'driver'; `direction` 'both', 'left' or 'right'; `fit` 'ols', 'level' for a flagged
line replaced by the driver's level, or 'paper'), skipped, k_scores; `meta.json` holds the
settings, code version, data fingerprint and summary numbers (with the feature sets measured,
presses by direction, flagged fits and warnings).
"""
