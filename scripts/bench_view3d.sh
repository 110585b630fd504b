#!/usr/bin/env bash
# Frame rate of DIR/view3d.html while the camera orbits, in headless Chromium's software
# renderer (SwiftShader) at 1280x800, and the time until the page is ready; RUNS runs (5).
# BROWSER=firefox measures headless Firefox ESR instead (software WebGL: Mesa llvmpipe on EGL).
# Usage: scripts/bench_view3d.sh DIR [RUNS] [HASH_OPTIONS]   e.g. ... out 5 density=2
set -euo pipefail
[ $# -ge 1 ] || { sed -n '2,4p' "$0" | sed 's/^# \{0,1\}//'; exit 2; }
page="$(cd "$1" && pwd)/view3d.html"
[ -f "$page" ] || { echo "bench_view3d: $page: no such file (run flashtwin run without --no-report)" >&2; exit 2; }
browser=${BROWSER:-chromium}
case "$browser" in
  chromium) command -v chromium >/dev/null || { echo "bench_view3d: chromium not found (apt-get install chromium)" >&2; exit 2; } ;;
  firefox) command -v firefox-esr >/dev/null || { echo "bench_view3d: firefox-esr not found (apt-get install firefox-esr)" >&2; exit 2; } ;;
  *) echo "bench_view3d: BROWSER=$browser: expected chromium or firefox" >&2; exit 2 ;;
esac
runs=${2:-5}
extra=${3:+&$3}
echo "$(basename "$(dirname "$page")")/view3d.html: $(stat -c %s "$page") bytes ($browser)"
if [ "$browser" = firefox ]; then
  profile=$(mktemp -d)
  trap 'rm -rf "$profile"' EXIT
  printf 'user_pref("devtools.console.stdout.content", true);\nuser_pref("webgl.force-enabled", true);\n' >"$profile/user.js"
  for ((i = 1; i <= runs; ++i)); do
    MOZ_WEBGL_FORCE_EGL=1 EGL_PLATFORM=surfaceless timeout 20 firefox-esr --headless --profile "$profile" \
      --width 1280 --height 800 "file://$page#bench$extra" 2>&1 |
      grep -o "ft-ready ms=[0-9]*\|ft-bench [^\"]*" | tr '\n' ' ' || true
    echo
  done
  exit 0
fi
for ((i = 1; i <= runs; ++i)); do
  # The page logs its frame rate to the console after orbiting for 5 s; Chromium stays up.
  timeout 15 chromium --headless --no-sandbox --disable-gpu --use-angle=swiftshader \
    --enable-unsafe-swiftshader --hide-scrollbars --window-size=1280,800 \
    --enable-logging=stderr --v=0 "file://$page#bench$extra" 2>&1 |
    grep -o "ft-ready ms=[0-9]*\|ft-bench [^\"]*" | tr '\n' ' ' || true
  echo
done
