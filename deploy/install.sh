#!/usr/bin/env bash
# Install swarmd's system files on a robot: user, directories, systemd units, udev rule,
# config skeleton. Idempotent: running it again changes nothing that is already right,
# and it never overwrites a config or key an operator wrote. See docs/operations.md.
#
#   deploy/install.sh [--root DIR] [--bin PATH] [--enable]    install
#   deploy/install.sh [--root DIR] --uninstall [--purge]      remove
#
# --root DIR   lay everything down under DIR (an image being built, or a test). The
#              host is not touched then: the user is declared in
#              DIR/usr/lib/sysusers.d/swarmd.conf and created by systemd-sysusers when
#              that system boots; no chown, no systemctl, no udevadm.
# --bin PATH   the swarmd executable the units run (default: `command -v swarmd`, else
#              /usr/local/bin/swarmd). With pipx or a venv: /opt/swarmd/bin/swarmd.
# --enable     also `systemctl enable swarmd` (host installs only; not started).
# --uninstall  remove units, udev rule and sysusers entry; keep /etc/swarmd (config and
#              swarm key) and /var/lib/swarmd (persisted epochs) unless --purge.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root=/
bin=""
action=install
purge=0
enable=0

usage() { sed -n '2,17p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }

while [ $# -gt 0 ]; do
  case "$1" in
    --root) root="${2:?--root needs a directory}"; shift 2 ;;
    --root=*) root="${1#--root=}"; shift ;;
    --bin) bin="${2:?--bin needs a path}"; shift 2 ;;
    --bin=*) bin="${1#--bin=}"; shift ;;
    --uninstall) action=uninstall; shift ;;
    --purge) purge=1; shift ;;
    --enable) enable=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "install.sh: unknown argument $1" >&2; usage >&2; exit 2 ;;
  esac
done

if [ ! -d "$root" ]; then
  echo "install.sh: --root $root is not a directory" >&2
  exit 2
fi
root="$(cd "$root" && pwd)"
host=0
[ "$root" = / ] && host=1
# Paths below are written as $R/etc/...; R is empty for the host so messages read well.
R="${root%/}"

if [ "$host" = 1 ] && [ "$(id -u)" -ne 0 ]; then
  echo "install.sh: installing on this host needs root (or use --root DIR)" >&2
  exit 1
fi

unitdir="$R/etc/systemd/system"
udevdir="$R/etc/udev/rules.d"
sysusersdir="$R/usr/lib/sysusers.d"
docdir="$R/usr/local/share/doc/swarmd"
confdir="$R/etc/swarmd"
statedir="$R/var/lib/swarmd"
logdir="$R/var/log/swarmd"

say() { echo "install.sh: $*"; }

# Copy src to dst only when the content differs, with the given mode: a re-run leaves
# files (and their timestamps) alone, and prints only what it changed.
put() {
  local mode="$1" src="$2" dst="$3"
  mkdir -p "$(dirname "$dst")"
  if [ -f "$dst" ] && cmp -s "$src" "$dst"; then
    chmod "$mode" "$dst"
    return 0
  fi
  install -m "$mode" "$src" "$dst"
  say "wrote $dst"
}

changed_units=0

install_all() {
  if [ -z "$bin" ]; then
    bin="$(command -v swarmd || true)"
    [ -n "$bin" ] || bin=/usr/local/bin/swarmd
  fi
  case "$bin" in
    /*) ;;
    *) echo "install.sh: --bin must be an absolute path (systemd requires it): $bin" >&2; exit 2 ;;
  esac
  if [ "$host" = 1 ] && [ ! -x "$bin" ]; then
    say "warning: $bin is not executable yet; install swarmd there (pip install .) before starting"
  fi

  tmp="$(mktemp -d)"
  trap 'rm -rf "$tmp"' EXIT

  # sysusers.d: the portable declaration of the user (systemd-sysusers(8)); dialout
  # membership for serial radios (DESIGN section 4).
  cat > "$tmp/sysusers.conf" <<'EOF'
# swarmd daemon user (deploy/install.sh). Member of dialout for serial radios.
u swarmd - "swarmd robot swarm daemon" /var/lib/swarmd
m swarmd dialout
EOF
  put 0644 "$tmp/sysusers.conf" "$sysusersdir/swarmd.conf"

  for unit in swarmd.service swarmd@.service; do
    sed "s|/usr/local/bin/swarmd|$bin|g" "$here/$unit" > "$tmp/$unit"
    if ! { [ -f "$unitdir/$unit" ] && cmp -s "$tmp/$unit" "$unitdir/$unit"; }; then
      changed_units=1
    fi
    put 0644 "$tmp/$unit" "$unitdir/$unit"
  done
  put 0644 "$here/99-swarmd-xbee.rules" "$udevdir/99-swarmd-xbee.rules"
  if [ -f "$here/../docs/operations.md" ]; then
    put 0644 "$here/../docs/operations.md" "$docdir/operations.md"
  fi

  mkdir -p "$confdir" "$statedir" "$logdir"
  chmod 0750 "$confdir" "$logdir"
  chmod 0700 "$statedir"
  # Never overwrite an operator's config: the skeleton goes in only if none exists.
  if [ ! -e "$confdir/robot.yaml" ]; then
    install -m 0640 "$here/robot.yaml.example" "$confdir/robot.yaml"
    say "wrote $confdir/robot.yaml (skeleton: edit robot id, swarm file, transport)"
  fi
  put 0644 "$here/robot.yaml.example" "$confdir/robot.yaml.example"

  if [ "$host" = 1 ]; then
    if ! getent passwd swarmd >/dev/null; then
      if command -v systemd-sysusers >/dev/null; then
        systemd-sysusers "$sysusersdir/swarmd.conf"
      else
        getent group dialout >/dev/null || groupadd --system dialout
        useradd --system --user-group --groups dialout --home-dir /var/lib/swarmd \
          --no-create-home --shell /usr/sbin/nologin --comment "swarmd robot swarm daemon" swarmd
      fi
      say "created system user swarmd (groups: swarmd, dialout)"
    elif ! id -nG swarmd | tr ' ' '\n' | grep -qx dialout; then
      usermod -a -G dialout swarmd
      say "added swarmd to dialout"
    fi
    chown root:swarmd "$confdir"
    chown root:swarmd "$confdir/robot.yaml" 2>/dev/null || true
    chown swarmd:swarmd "$statedir" "$logdir"
    if [ -d /run/systemd/system ]; then
      if [ "$changed_units" = 1 ]; then systemctl daemon-reload; fi
      if [ "$enable" = 1 ]; then systemctl enable swarmd.service; fi
    fi
    if command -v udevadm >/dev/null && [ -d /run/udev ]; then
      udevadm control --reload-rules
      udevadm trigger --subsystem-match=tty --action=add
    fi
  else
    say "installed under $root; the swarmd user is created by systemd-sysusers at boot"
  fi
  say "done. Next: swarmd keygen (once per swarm), edit $confdir/robot.yaml, then"
  say "  systemctl enable --now swarmd && journalctl -u swarmd -f   (docs/operations.md)"
}

uninstall_all() {
  if [ "$host" = 1 ] && [ -d /run/systemd/system ]; then
    systemctl disable --now swarmd.service 2>/dev/null || true
  fi
  local f
  for f in "$unitdir/swarmd.service" "$unitdir/swarmd@.service" \
           "$udevdir/99-swarmd-xbee.rules" "$sysusersdir/swarmd.conf" \
           "$docdir/operations.md" "$confdir/robot.yaml.example"; do
    if [ -e "$f" ]; then
      rm -f "$f"
      say "removed $f"
    fi
  done
  rmdir "$docdir" 2>/dev/null || true
  if [ "$purge" = 1 ]; then
    for f in "$confdir" "$statedir" "$logdir"; do
      if [ -e "$f" ]; then
        rm -rf "$f"
        say "removed $f"
      fi
    done
    if [ "$host" = 1 ] && getent passwd swarmd >/dev/null; then
      userdel swarmd
      say "removed user swarmd"
    fi
  else
    say "kept $confdir (config, swarm key) and $statedir (persisted epochs): --purge removes them"
  fi
  if [ "$host" = 1 ] && [ -d /run/systemd/system ]; then
    systemctl daemon-reload
  fi
}

case "$action" in
  install) install_all ;;
  uninstall) uninstall_all ;;
esac
