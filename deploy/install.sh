#!/usr/bin/env bash
# Install the formation robot agent on a robot (Raspberry Pi class Linux board, systemd), or,
# with --coordinator-host, the coordinator host (router, coordinators, camera tracker).
#
# What it does (each step is idempotent: running it again upgrades in place):
#   1. builds a wheel of this project (`python -m build` if available, else
#      `python -m pip wheel --no-deps`), or uses the one given with --wheel;
#   2. creates the virtualenv /opt/formation/venv (kept if it exists) and installs the
#      wheel with the `agent` extra only (eclipse-zenoh, msgpack, pyserial; no numpy);
#   3. creates the unprivileged system user `formation` (group `formation`, member of
#      `dialout` for the serial port);
#   4. installs the systemd unit formation-agent@.service, the udev rule for /dev/roboclaw,
#      the Zenoh configurations (/etc/formation/zenoh/), the example robot config, the
#      certificate script and the deployment guide; creates /etc/formation/certs (0750);
#      with --robot-id ID, creates /etc/formation/ID.toml from the example if it is absent
#      (an existing robot config is never overwritten);
#   5. reloads systemd and udev. It does not enable or start the unit.
#
# With --coordinator-host instead: the wheel with the `sim` and `camera` extras; the user
# `formation` (group `video` for the camera); the units formation-router.service,
# formation-coordinator@.service, formation-camera.service and formation-ros2.service (the ROS 2
# bridge, docs/ros2.md); every Zenoh config but the
# robot's; /etc/formation/fleet.toml (from the example, if absent), camera.env (if absent) and
# coordinator-standby.env (--standby for formation-coordinator@standby).
#
# usage: sudo deploy/install.sh [--coordinator-host] [--prefix DIR] [--dry-run] [--robot-id ID]
#                               [--files-only] [--wheel FILE] [--python PYTHON]
#   --coordinator-host  install the coordinator host instead of a robot.
#   --prefix DIR   stage everything under DIR instead of / (paths inside the files stay the
#                  final ones, like DESTDIR); no user is created and nothing is reloaded.
#   --dry-run      print every command instead of running it; changes nothing.
#   --robot-id ID  also create /etc/formation/ID.toml from the example (if absent).
#   --files-only   skip the wheel, the virtualenv and pip (configuration files only).
#   --wheel FILE   install this wheel instead of building one.
#   --python PY    the interpreter for the virtualenv (default: python3; needs >= 3.11).
#   --accel        also compile the firmware core on this board with mypyc (needs gcc and the
#                  Python headers: apt install gcc python3-dev): about 2x faster ticks, the
#                  same outputs bit for bit (checked before the build is installed). mypy is
#                  installed for the build and removed after; if the build fails the
#                  pure-Python core runs. Run it again after every upgrade (a build of older
#                  sources is never used).
set -euo pipefail

script_dir="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo_dir="$(cd "$script_dir/.." && pwd)"

prefix=""
dry_run=0
robot_id=""
files_only=0
coordinator_host=0
wheel=""
python="python3"
accel=0

usage() {
    sed -n '2,/^set -euo/p' "$0" | sed -e '$d' -e 's/^# \{0,1\}//'
}

while [[ $# -gt 0 ]]; do
    case "$1" in
        --prefix) prefix="${2:?--prefix needs a directory}"; shift 2 ;;
        --dry-run) dry_run=1; shift ;;
        --robot-id) robot_id="${2:?--robot-id needs an id}"; shift 2 ;;
        --files-only) files_only=1; shift ;;
        --coordinator-host) coordinator_host=1; shift ;;
        --wheel) wheel="${2:?--wheel needs a file}"; shift 2 ;;
        --python) python="${2:?--python needs an interpreter}"; shift 2 ;;
        --accel) accel=1; shift ;;
        -h|--help) usage; exit 0 ;;
        *) echo "install.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done

if [[ $coordinator_host -eq 1 && -n "$robot_id" ]]; then
    echo "install.sh: --robot-id is for a robot, not with --coordinator-host" >&2
    exit 2
fi
if [[ $accel -eq 1 && $files_only -eq 1 ]]; then
    echo "install.sh: --accel compiles the installed code; not with --files-only" >&2
    exit 2
fi
extras="agent"
[[ $coordinator_host -eq 1 ]] && extras="sim,camera"
if [[ -n "$robot_id" && ! "$robot_id" =~ ^[a-z0-9_-]+$ ]]; then
    echo "install.sh: --robot-id '$robot_id' must match [a-z0-9_-]+" >&2
    exit 2
fi
if [[ -n "$prefix" ]]; then
    prefix="$(realpath -m "$prefix")"
    [[ "$prefix" == "/" ]] && prefix=""
fi
system_install=0
[[ -z "$prefix" ]] && system_install=1

venv_dir="/opt/formation/venv"
share_dir="/opt/formation/share"
etc_dir="/etc/formation"
unit_dir="/etc/systemd/system"
udev_dir="/etc/udev/rules.d"

say() { echo "install.sh: $*"; }

# run CMD...: execute, or print it under --dry-run.
run() {
    if [[ $dry_run -eq 1 ]]; then
        printf '+'
        printf ' %q' "$@"
        printf '\n'
    else
        "$@"
    fi
}

# put MODE SRC DEST: install one file (DEST is a final path; the prefix is added here).
put() {
    run install -D -m "$1" "$2" "$prefix$3"
}

if [[ $system_install -eq 1 && $dry_run -eq 0 && $EUID -ne 0 ]]; then
    echo "install.sh: a system install needs root (sudo), or use --prefix/--dry-run" >&2
    exit 1
fi

# ---------------------------------------------------------------- 1-2. wheel and venv
if [[ $files_only -eq 0 ]]; then
    if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
        echo "install.sh: $python is missing or older than Python 3.11" >&2
        exit 1
    fi
    build_dir=""
    if [[ -z "$wheel" ]]; then
        if [[ $dry_run -eq 1 ]]; then
            build_dir="<temporary directory>"
        else
            build_dir="$(mktemp -d)"
            trap 'rm -rf "$build_dir"' EXIT
        fi
        if "$python" -c 'import build' 2>/dev/null; then
            say "building the wheel with python -m build"
            run "$python" -m build --wheel --outdir "$build_dir" "$repo_dir"
        else
            say "building the wheel with pip wheel (python -m build is not installed)"
            run "$python" -m pip wheel --no-deps --wheel-dir "$build_dir" "$repo_dir"
        fi
        if [[ $dry_run -eq 1 ]]; then
            wheel="$build_dir/formation_control-<version>-py3-none-any.whl"
        else
            wheel="$(ls -t "$build_dir"/formation_control-*.whl | head -n 1)"
        fi
    elif [[ ! -f "$wheel" ]]; then
        echo "install.sh: wheel $wheel not found" >&2
        exit 1
    fi
    venv="$prefix$venv_dir"
    if [[ -x "$venv/bin/python" ]]; then
        say "keeping the existing virtualenv $venv"
    else
        run "$python" -m venv "$venv"
    fi
    # the agent extra pulls the robot's dependencies (sim,camera: the coordinator host's); the
    # second call replaces this project's code even when the version number did not change
    run "$venv/bin/python" -m pip install --upgrade "$wheel[$extras]"
    run "$venv/bin/python" -m pip install --force-reinstall --no-deps "$wheel"
    if [[ $accel -eq 1 ]]; then
        say "compiling the firmware core (mypyc); the build tools are removed after"
        run "$venv/bin/python" -m pip install 'mypy>=1.10' 'setuptools>=68'
        run "$venv/bin/python" -P -m robot_agent.buildtools.accel build \
            || say "the compiled core was not built: the pure-Python core runs"
        run "$venv/bin/python" -m pip uninstall -y mypy
        run "$venv/bin/python" -P -m robot_agent.buildtools.accel status || true
    fi
else
    say "--files-only: skipping the wheel and the virtualenv"
fi

# ---------------------------------------------------------------- 3. user
if [[ $system_install -eq 1 ]]; then
    if getent passwd formation >/dev/null; then
        say "user formation exists"
    else
        run useradd --system --user-group --no-create-home --home-dir /nonexistent \
            --shell /usr/sbin/nologin --comment "formation robot agent" formation
    fi
    device_group="dialout"
    [[ $coordinator_host -eq 1 ]] && device_group="video"
    if getent group "$device_group" >/dev/null; then
        run usermod --append --groups "$device_group" formation
    else
        say "warning: no $device_group group on this system; the device needs another group"
    fi
else
    say "prefix install: not creating the user formation (done by a system install)"
fi

# ---------------------------------------------------------------- 4. files
# keep SRC DEST: install SRC at DEST only if DEST is absent (site files are never overwritten)
keep() {
    if [[ -e "$prefix$2" ]]; then
        say "keeping the existing $2"
    else
        run install -D -m 0640 "$1" "$prefix$2"
        if [[ $system_install -eq 1 && $dry_run -eq 0 ]]; then chown root:formation "$2"; fi
    fi
}
if [[ $coordinator_host -eq 1 ]]; then
    for u in formation-router.service formation-coordinator@.service formation-camera.service \
        formation-ros2.service; do
        put 0644 "$script_dir/systemd/$u" "$unit_dir/$u"
    done
    for f in "$script_dir"/zenoh/*.json5; do
        name="$(basename "$f")"
        [[ "$name" == robot-mtls.json5 ]] && continue
        put 0644 "$f" "$etc_dir/zenoh/$name"
    done
    put 0644 "$script_dir/config/fleet.example.toml" "$etc_dir/fleet.example.toml"
    put 0644 "$script_dir/config/camera.env.example" "$etc_dir/camera.env.example"
    keep "$script_dir/config/fleet.example.toml" "$etc_dir/fleet.toml"
    keep "$script_dir/config/camera.env.example" "$etc_dir/camera.env"
    keep "$script_dir/config/coordinator-standby.env" "$etc_dir/coordinator-standby.env"
else
    put 0644 "$script_dir/systemd/formation-agent@.service" "$unit_dir/formation-agent@.service"
    put 0644 "$script_dir/udev/99-formation-roboclaw.rules" "$udev_dir/99-formation-roboclaw.rules"
    for f in client.json5 robot-mtls.json5; do
        put 0644 "$script_dir/zenoh/$f" "$etc_dir/zenoh/$f"
    done
    put 0644 "$script_dir/config/r1.example.toml" "$etc_dir/r1.example.toml"
fi
put 0755 "$script_dir/security/gen-certs.sh" "$share_dir/gen-certs.sh"
put 0644 "$script_dir/install.sh" "$share_dir/install.sh"
if [[ -f "$repo_dir/docs/deploy.md" ]]; then
    put 0644 "$repo_dir/docs/deploy.md" "$share_dir/docs/deploy.md"
fi
if [[ -f "$repo_dir/docs/localization.md" ]]; then
    put 0644 "$repo_dir/docs/localization.md" "$share_dir/docs/localization.md"
fi
run install -d -m 0750 "$prefix$etc_dir/certs"
if [[ $system_install -eq 1 ]]; then
    run chown root:formation "$etc_dir/certs"
fi

if [[ -n "$robot_id" ]]; then
    target="$prefix$etc_dir/$robot_id.toml"
    if [[ -e "$target" ]]; then
        say "keeping the existing $etc_dir/$robot_id.toml"
    elif [[ $dry_run -eq 1 ]]; then
        printf '+ sed s/^robot_id = "r1"/robot_id = "%s"/ %q > %q\n' \
            "$robot_id" "$script_dir/config/r1.example.toml" "$target"
    else
        sed "s/^robot_id = \"r1\"/robot_id = \"$robot_id\"/" \
            "$script_dir/config/r1.example.toml" >"$target"
        chmod 0640 "$target"
        if [[ $system_install -eq 1 ]]; then chown root:formation "$target"; fi
        say "created $etc_dir/$robot_id.toml: edit it, then check it (see below)"
    fi
fi

# ---------------------------------------------------------------- 5. reload
if [[ $system_install -eq 1 ]]; then
    if command -v systemctl >/dev/null && [[ -d /run/systemd/system ]]; then
        run systemctl daemon-reload
    fi
    if command -v udevadm >/dev/null; then
        run udevadm control --reload-rules
        run udevadm trigger --subsystem-match=tty --action=add
    fi
fi

if [[ $coordinator_host -eq 1 ]]; then
    say "done. Next steps (docs/deploy.md):"
    echo "  1. certificates: copy router/, coordinator.main/, coordinator.standby/, localization/, operator/, observer/ from formation certs into $etc_dir/certs/"
    echo "  2. fleet:        edit $etc_dir/fleet.toml, then: $venv_dir/bin/formation coordinator --check --fleet-file $etc_dir/fleet.toml"
    echo "  3. camera:       $etc_dir/camera.toml (formation camera calibrate) and $etc_dir/camera.env"
    echo "  4. start:        systemctl enable --now formation-router formation-coordinator@main formation-coordinator@standby formation-camera"
    echo "  5. watch:        $venv_dir/bin/formation top --zenoh-config $etc_dir/zenoh/observer-mtls.json5"
    exit 0
fi
id_hint="${robot_id:-<id>}"
say "done. Next steps:"
echo "  1. certificates: copy robot.$id_hint/{ca,cert,key}.pem from formation certs (or gen-certs.sh) into $etc_dir/certs/"
echo "  2. config:       $etc_dir/$id_hint.toml (template: $etc_dir/r1.example.toml)"
echo "  3. check:        $venv_dir/bin/formation agent --check-config $etc_dir/$id_hint.toml"
echo "  4. start:        systemctl enable --now formation-agent@$id_hint"
echo "  5. watch:        journalctl -u formation-agent@$id_hint -f"
