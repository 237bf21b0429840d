"""Dashboard: the Streamlit app over the workspace (the only package importing streamlit).

Run it with `laneprint dashboard [--workspace W] [--port P] [--host H]` (127.0.0.1:8501
by default, headless, no usage statistics, uploads up to 1024 MB), or
`streamlit run dashboard/app.py -- --workspace W`.

- `app.py`: `st.navigation` over the pages in `app_pages/` (Data, Drivers, Styles,
  Training, Results); each page is a thin `main()` calling the modules below and the
  stages' own functions and plots.
- `context.py`: the workspace (`--workspace` after `--`, else $LANEPRINT_WORKSPACE)
  and the tunables read from the environment: $LANEPRINT_DASHBOARD_EPISODES (episodes
  pre-filled in the Training form, and the Personalise page's base agents'), $LANEPRINT_DASHBOARD_POLL_S (refresh of the live
  training view, default 1 s), $LANEPRINT_DASHBOARD_MAX_UPLOAD_MB (default 1024).
- `docs_site.py`: the documentation site built into `static/docs/` and served by Streamlit's static
  route (`laneprint dashboard` builds it when stale); `more(key)`, the help texts' links to its pages.
- `loaders.py`: cached readers keyed on the modification times of the folders they read.
- `uploads.py`: browser uploads saved under `workspace/uploads/<hash>/<safe name>`.
- `jobs.py`: `laneprint train`, `laneprint train --drivers all | --styles all` (a fleet)
  and `laneprint crossval --run RUN_ID` subprocesses (own session, so they outlive the
  page and the server), their status and progress, cancel (SIGTERM). A launched fleet
  is tied to its `fleets/<id>/fleet.json` by the trainer's pid.
- `training.py`, `views.py`, `figures.py`, `widgets.py`: form defaults, table shaping,
  the recording viewer, the held-out vs in-sample figures, layout helpers and the
  cross-validation launcher shared by the Training and Results pages.

Held-out figures: a finished run is cross-validated from the Training page (or the
Results page, when it has none yet); the Results page shows the run's
`runs/<id>/crossval.json` (else the newest cross-validation of its target, said so)
beside its in-sample evaluation, and lists every stored cross-validation.

Fleets: the Training page launches one (every driver or every style, N seeds) and
follows it live (agents done, episodes summed over its runs' status.json, a table of
each agent's figures as it is evaluated); the Results page's Fleets section shows any
fleet (`rl.fleet.store`) as one sortable row per agent and a dot plot of each target's
agent, greedy and imitation balanced accuracy.
"""
