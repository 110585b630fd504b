#!/usr/bin/env bash
# The main job: install what is missing, build, and run the default scenario end to end
# (scan, perception, planning, grinding in MuJoCo, scoring) → out/default/run/report.html;
# then the cell, scan, registration, renders and the kinematics demo into out/default/.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
FT=build/apps/flashtwin
OUT=out/default
mkdir -p "$OUT"
$FT cell scenarios/default.yaml -o "$OUT"
$FT scan scenarios/default.yaml -o "$OUT"
echo "--- pose of the casting from its scan (registration to the CAD model):"
$FT register --source "$OUT/scan.ply" --target "$OUT/cell/casting_cad.stl" --remove-plane \
  --viewpoint "0 0 0" | tee "$OUT/registration.txt"
echo "--- the closed loop: scan, registration, flash detection, planning, grinding, scoring:"
$FT run scenarios/default.yaml -o "$OUT/run"
$FT render scenarios/default.yaml -o "$OUT"
$FT render scenarios/default.yaml -o "$OUT" --truth --camera casting_closeup
$FT workspace --samples 200000 -o "$OUT"
echo "--- forward kinematics at q = (0, -60, 30, 0, 45, 0) deg:"
$FT fk --deg --q "0 -60 30 0 45 0" | tee "$OUT/fk.txt"
pose=$($FT fk --deg --q "0 -60 30 0 45 0" --json | sed -E 's/.*"X_BE":\[([^]]*)\].*/\1/')
echo "--- inverse kinematics of that flange pose (all solutions within limits, degrees):"
$FT ik --deg --pose "$pose" | tee "$OUT/ik.txt"
echo
echo "Outputs in $(pwd)/$OUT: cell.xml (open with: mujoco-simulate $OUT/cell.xml), robot.urdf,"
echo "casting_cad.stl, scan.ply/.pcd/.json, registration.txt, render_*.png, scan_casting_closeup.png,"
echo "workspace.png, fk.txt, ik.txt; run/metrics.json, run/paths.json, run/trajectory.csv, run/plan/"
echo "Report of the run: $(pwd)/$OUT/run/report.html"
