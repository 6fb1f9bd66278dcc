#!/usr/bin/env bash
# The Debian package: builds it from this build directory (cpack -G DEB), unpacks it into a
# scratch root (dpkg-deb -x) and checks what a drive engineer installs: the layout, the
# conffiles, the maintainer scripts, the dependencies, that every program in it answers
# --version with this version and that the shipped configurations pass pmsm-thermald --check.
# lintian's findings are printed (not a failure; docs/deploy.md lists them).
#   tests/unit/package_deb.sh BUILD_DIR VERSION
set -euo pipefail
build=$1 version=$2
for tool in cpack dpkg-deb dpkg-shlibdeps; do
  command -v "$tool" >/dev/null || { echo "$tool is not installed: skipped" >&2; exit 77; }
done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "package: FAIL: $*" >&2; exit 1; }

(cd "$build" && cpack -G DEB -B "$work/out" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; fail "cpack failed"; }
deb="$work/out/pmsm-thermal_${version}_$(dpkg --print-architecture).deb"
[ -f "$deb" ] || fail "no $deb (cpack wrote: $(ls "$work/out"))"
echo "package: $(basename "$deb"), $(stat -c %s "$deb") bytes"

root="$work/root"
dpkg-deb -x "$deb" "$root"
for f in usr/sbin/pmsm-thermald usr/bin/pmsm-plant usr/bin/pmsm-thermal \
         usr/lib/systemd/system/pmsm-thermald@.service usr/lib/systemd/system/pmsm-plant@.service \
         usr/lib/systemd/network/80-vcan0.netdev usr/lib/systemd/network/80-vcan0.network \
         usr/lib/modules-load.d/pmsm-thermal.conf usr/lib/sysusers.d/pmsm-thermal.conf \
         etc/pmsm-thermal/axis1.toml etc/pmsm-thermal/plant-axis1.toml etc/pmsm-thermal/plant-axis1.env \
         usr/share/pmsm-thermal/pmsm-thermal.dbc usr/share/pmsm-thermal/plant-profiles/reference.toml \
         usr/share/doc/pmsm-thermal/changelog.gz \
         usr/share/doc/pmsm-thermal/copyright \
         usr/share/man/man8/pmsm-thermald.8.gz usr/share/man/man1/pmsm-plant.1.gz usr/share/man/man1/pmsm-thermal.1.gz; do
  [ -e "$root/$f" ] || fail "missing /$f"
done
# Nothing outside the FHS places a package may use, nothing under /usr/local or /usr/etc.
unexpected=$(cd "$root" && find . -mindepth 1 -maxdepth 2 | grep -v -E '^\./(usr|etc)(/(bin|sbin|lib|share|pmsm-thermal))?$' || true)
[ -z "$unexpected" ] || fail "unexpected paths: $unexpected"
# The units name the paths the package installs.
grep -q '^ExecStart=/usr/sbin/pmsm-thermald ' "$root/usr/lib/systemd/system/pmsm-thermald@.service" || fail "pmsm-thermald@.service does not start /usr/sbin/pmsm-thermald"
grep -q '^ExecStart=/usr/bin/pmsm-plant ' "$root/usr/lib/systemd/system/pmsm-plant@.service" || fail "pmsm-plant@.service does not start /usr/bin/pmsm-plant"
grep -q '^u pmsm-thermal ' "$root/usr/lib/sysusers.d/pmsm-thermal.conf" || fail "sysusers.d does not create pmsm-thermal"

# Control: conffiles are exactly the /etc files; maintainer scripts create the user.
control="$work/control"
dpkg-deb -e "$deb" "$control"
diff <(sort "$control/conffiles") <(cd "$root" && find etc -type f | sed 's#^#/#' | sort) \
  || fail "conffiles differ from the files in /etc"
grep -q 'systemd-sysusers /usr/lib/sysusers.d/pmsm-thermal.conf' "$control/postinst" || fail "postinst does not create the user"
sh -n "$control/postinst" && sh -n "$control/prerm" && sh -n "$control/postrm" || fail "a maintainer script is not valid sh"
grep -q 'deb-systemd-invoke stop "$unit"' "$control/prerm" || fail "prerm does not stop the running instances on removal"
grep -q 'systemctl stop "$unit"' "$control/prerm" || fail "prerm does not stop, whatever policy-rc.d says, the instances still running"
[ "$(dpkg-deb -f "$deb" Version)" = "$version" ] || fail "Version is $(dpkg-deb -f "$deb" Version), not $version"
depends=$(dpkg-deb -f "$deb" Depends)
for lib in libspdlog libfmt libtomlplusplus libgpiod libsystemd0 libstdc++6; do
  case "$depends" in *"$lib"*) ;; *) fail "Depends lacks $lib: $depends" ;; esac
done
echo "package: Depends: $depends"

# The programs as installed: --version, and the shipped configurations are valid.
for exe in usr/sbin/pmsm-thermald usr/bin/pmsm-plant usr/bin/pmsm-thermal; do
  out=$("$root/$exe" --version) || fail "/$exe --version failed"
  [ "$out" = "$(basename "$exe") $version" ] || fail "/$exe --version says '$out'"
done
"$root/usr/sbin/pmsm-thermald" --check --config "$root/etc/pmsm-thermal/axis1.toml" >"$work/check.log" 2>&1 \
  || { cat "$work/check.log"; fail "the shipped axis1.toml fails pmsm-thermald --check"; }
"$root/usr/bin/pmsm-plant" --check --config "$root/etc/pmsm-thermal/plant-axis1.toml" >"$work/check.log" 2>&1 \
  || { cat "$work/check.log"; fail "the shipped plant-axis1.toml fails pmsm-plant --check"; }
for p in "$root"/usr/share/pmsm-thermal/plant-profiles/*.toml; do
  "$root/usr/bin/pmsm-plant" --check --config "$p" >/dev/null 2>&1 || fail "$(basename "$p") fails pmsm-plant --check"
done
# The packaged DBC is what the installed tool generates for node 0, and it makes the shipped
# axis1.toml's (node 1) too.
"$root/usr/bin/pmsm-thermal" dbc | cmp -s - "$root/usr/share/pmsm-thermal/pmsm-thermal.dbc" \
  || fail "the packaged DBC differs from \`pmsm-thermal dbc\` (node 0)"
node=$(sed -n 's/^node *= *\([0-9]*\).*/\1/p' "$root/etc/pmsm-thermal/axis1.toml" | head -1)
[ -n "$node" ] || fail "the shipped axis1.toml names no can.node"
"$root/usr/bin/pmsm-thermal" dbc --node "$node" -o "$work/node.dbc" || fail "\`pmsm-thermal dbc --node $node\` failed"
grep -q "^BA_ \"ProtocolNodeId\" $node;" "$work/node.dbc" \
  || fail "\`pmsm-thermal dbc --node $node\` does not describe node $node"
echo "package: layout, conffiles, maintainer scripts, Depends, --version, the shipped configurations and DBCs: ok"

if command -v lintian >/dev/null; then
  echo "package: lintian:"
  lintian --tag-display-limit 0 "$deb" 2>&1 | grep -v 'running with root privileges' | sed 's/^/  /' || true
fi
