"""Clustering: drivers into styles, typical drivers and reference lines.

- `features`: per driver, a robust line (Huber on log TTC by default) of each of
  `feature_indicators` (t_f, t_nf) evaluated at 60/70/80/90 km/h.
- `styles`: `StyleClusterer` (scikit-learn-like): robust standardisation, median imputation
  of missing features, k-means (k fixed or chosen by silhouette/BIC), clusters ordered and
  named by defensiveness (larger TTCs at the decision = more defensive), mixture posterior.
- `confidence`: bootstrap stability of each assignment (the `confidence` column when computed).
- `pipeline`: `analyze_tables(decisions, settings)` (pure: correlations, fits, styles,
  reference lines, skipped) and `analyze(workspace, settings, progress)` (reads every
  recording, writes the `analysis/` stage in one swap, returns the JSON-ready report).
- `plots`: `cluster_scatter`, `reference_lines` (Plotly figures).
- `cli`: `laneprint analyze`.

Tables in `analysis/`: decisions, correlations, fits, styles, reference_lines (scope 'style'
with kinds 'typical', 'pooled', 'paper'; scope 'driver' with kind 'driver'), skipped, k_scores;
`meta.json` holds the settings, code version, data fingerprint and summary numbers.
"""
