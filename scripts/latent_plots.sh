#!/usr/bin/env bash
# Redraws every plot of EXPERIMENTS section 9 (docs/latent/plots/*.png) from the archived runs in
# docs/latent/results, with scripts/plot_latent.py (mean ± sample sd over runs, the document's
# convention), and prints each plot's table: they must equal the section's tables.
#   usage: PY=path/to/python-with-matplotlib scripts/latent_plots.sh
#   (e.g. python3 -m venv runs/venv-plot && runs/venv-plot/bin/pip install matplotlib)
set -euo pipefail
cd "$(dirname "$0")/.."
py=${PY:-.venv-peers/bin/python}
R=docs/latent/results P=docs/latent/plots
j() { ls -d "$R"/pieces/"$1"-s* | paste -sd+; }
plot() { echo "== $1"; "$py" scripts/plot_latent.py "$@"; }
plot "$P/fig4_5_q_critic.png" "Planned exploration vs OU (Fig. 4.5), Q critic, pixel HalfCheetah" \
  "plan H=10=$R/plan-q-h10" "OU=$R/ou-q"
plot "$P/fig4_7_horizons.png" "Planning horizon (Fig. 4.7), Q critic, pixel HalfCheetah" \
  "H=1=$R/plan-q-h1" "H=10=$R/plan-q-h10" "H=20=$R/plan-q-h20" "OU=$R/ou-q"
plot "$P/fig4_8_objectives.png" "Planning objective (Fig. 4.8), Q critic, pixel HalfCheetah" \
  "sum of Q (Eq. 4.11)=$R/plan-q-h10" "reward + Q (Eq. 4.12)=$R/plan-q-rq" "last Q only=$R/plan-q-lastq"
plot --window 20 "$P/table4_1_reach.png" "Sparse reaching (stand-in for Table 4.1)" \
  "H=1=$R/reach-h1" "H=3=$R/reach-h3" "H=5=$R/reach-h5" "H=15=$R/reach-h15" "OU=$R/reach-ou"
plot "$P/fig4_6_v_critic.png" "Value critic (Fig. 4.6), pixel HalfCheetah" \
  "plan H=10, V critic (3000 updates)=$R/plan-v-h10" "OU, V critic (3000 updates)=$R/ou-v" \
  "plan H=10, Q critic (1000 updates; 9b)=$R/plan-q-h10" "OU, Q critic (1000 updates; 9b)=$R/ou-q"
plot "$P/dmc_fig4_5.png" "Planned exploration vs OU (Fig. 4.5), Q critic, DM Control cheetah" \
  "plan H=10=$R/dmc-plan-q" "OU=$R/dmc-ou-q"
plot "$P/dmc_fig4_7.png" "Planning horizon (Fig. 4.7), Q critic, DM Control cheetah" \
  "H=1=$(j dmc-plan-q-h1)" "H=10=$R/dmc-plan-q" "H=20=$(j dmc-plan-q-h20)" "OU=$R/dmc-ou-q"
plot "$P/dmc_fig4_8.png" "Planning objective (Fig. 4.8), Q critic, DM Control cheetah" \
  "sum of Q=$R/dmc-plan-q" "reward + Q=$(j dmc-plan-q-rq)" "last Q=$(j dmc-plan-q-lastq)"
plot "$P/dmc_fig4_6.png" "Value critic (Fig. 4.6), DM Control cheetah" \
  "plan H=10, V critic (3000 updates)=$(j dmc-plan-v)" "OU, V critic (3000 updates)=$(j dmc-ou-v)" \
  "plan H=10, Q critic (1000 updates)=$R/dmc-plan-q" "OU, Q critic (1000 updates)=$R/dmc-ou-q"
