"""Container images without a Docker engine: built from the repository's Dockerfiles.

    python e2e/bed/images.py build [--only NAME]    (make images)
    python e2e/bed/images.py list

* **Base**: a Debian bookworm rootfs from ``debootstrap --variant=minbase`` with Python 3.11
  (``python-is-python3``, ``python3-venv``), slimmed and packed as an OCI image. It stands in
  for the Dockerfiles' ``python:3.11-slim-bookworm`` (their ``ARG PYTHON_IMAGE``), which no
  registry here serves.
* **Images**: ``buildah bud --isolation chroot`` runs each Dockerfile as written (RUN steps
  reach PyPI), storage under the cache, not /var/lib/containers. Each result is a
  docker-archive tarball, which ``ctr images import``, ``k3d image import`` and
  ``kind load image-archive`` all take.
* **pause**: ``build/pause/linux/pause.c`` from the Kubernetes module, ``gcc -static``,
  packed with umoci: containerd's sandbox image, so no node ever pulls.
* **busybox**: Debian's static busybox, for the bed's own smoke tests.

Everything is cached in ``CACHE_ROOT/images/`` under a content hash of its recipe (the
Dockerfile, every file its COPY lines read, the base, the build args): an unchanged recipe is
never rebuilt. Nothing is pushed anywhere.
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import json
import shutil
import sys
import tarfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository root importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from e2e.bed.base import CACHE_ROOT, REPO_ROOT, HarnessError, load_versions, log, run
from e2e.bed.gomodule import GoToolchain
from e2e.bed.tools import install_debian_packages

IMAGES_DIR = CACHE_ROOT / "images"
IMAGE_PACKAGES = ("debootstrap", "umoci", "skopeo", "buildah", "busybox-static", "gcc", "libc6-dev")
BASE_SUITE = "bookworm"
BASE_INCLUDE = ("python3", "python3-venv", "python-is-python3", "ca-certificates")
BASE_REF = "localhost/fogfleet/python-base:3.11-bookworm"
PAUSE_REF = "localhost/fogfleet/pause:3.10"
BUSYBOX_REF = "localhost/fogfleet/busybox:bed"
# Host files lent to RUN steps as read-only bind mounts (not committed to the image).
HOST_TRUST = ("/etc/ssl/certs/ca-certificates.crt", "/etc/pip.conf")
# What the slim step removes from the base rootfs (docs, caches, apt lists).
SLIM = ("usr/share/doc", "usr/share/man", "usr/share/info", "usr/share/locale",
        "var/cache/apt", "var/lib/apt/lists", "var/log")  # fmt: skip


@dataclass(frozen=True)
class Recipe:
    """An image built from a Dockerfile in the repository (context: the repository root)."""

    name: str
    ref: str
    dockerfile: str
    build_args: dict[str, str] = field(default_factory=dict)

    @property
    def path(self) -> Path:
        return REPO_ROOT / self.dockerfile


RECIPES = (
    Recipe("operator", "ghcr.io/fogfleet/fogfleet:0.1.0", "Dockerfile"),
    Recipe("ros2-module", "ghcr.io/fogfleet/ros2-module:0.1.0", "workloads/ros2-module/Dockerfile"),
)


def _sha(*parts: bytes | str) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(part.encode() if isinstance(part, str) else part)
        h.update(b"\0")
    return h.hexdigest()[:16]


def _mirror() -> str:
    """The Debian mirror apt itself uses (deb822 or one-line sources)."""
    for path in [Path("/etc/apt/sources.list"), *sorted(Path("/etc/apt/sources.list.d").glob("*"))]:
        if not path.is_file() or path.suffix not in ("", ".list", ".sources"):
            continue
        for line in path.read_text().splitlines():
            words = line.split()
            if line.startswith("URIs:") and len(words) > 1 and "security" not in words[1]:
                return words[1]
            if (
                words[:1] == ["deb"]
                and len(words) > 2
                and "debian" in words[-3 if len(words) > 3 else 1]
            ):
                return next(w for w in words[1:] if w.startswith("http"))
    raise HarnessError("no Debian mirror in /etc/apt/sources.list{,.d}: debootstrap needs one")


# --------------------------------------------------------------------------------------------
# OCI plumbing: umoci builds a layer from a directory, skopeo converts to a docker-archive


def _pack_rootfs(rootfs: Path, ref: str, out: Path, config: list[str]) -> Path:
    """A single-layer image of `rootfs` as a docker-archive at `out` (tagged `ref`)."""
    work = out.with_suffix(".work")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    layout = work / "oci"
    run(["umoci", "init", "--layout", str(layout)])
    run(["umoci", "new", "--image", f"{layout}:img"])
    run(["umoci", "insert", "--image", f"{layout}:img", str(rootfs), "/"])
    if config:
        run(["umoci", "config", "--image", f"{layout}:img", *config])
    tmp = out.with_suffix(".tmp")
    tmp.unlink(missing_ok=True)
    run(["skopeo", "copy", "--quiet", f"oci:{layout}:img", f"docker-archive:{tmp}:{ref}"])
    tmp.replace(out)
    shutil.rmtree(work, ignore_errors=True)
    return out


def _cached(name: str, key: str) -> Path:
    return IMAGES_DIR / f"{name}-{key}.tar"


# --------------------------------------------------------------------------------------------
# the images


def base_archive() -> Path:
    """The Debian bookworm + Python 3.11 base, as a docker-archive (cached by its recipe)."""
    key = _sha(BASE_SUITE, *BASE_INCLUDE, *SLIM, "v1")
    out = _cached("python-base", key)
    if out.exists():
        return out
    install_debian_packages(IMAGE_PACKAGES)
    t0 = time.monotonic()
    rootfs = IMAGES_DIR / f"python-base-{key}.rootfs"
    shutil.rmtree(rootfs, ignore_errors=True)
    rootfs.parent.mkdir(parents=True, exist_ok=True)
    log(f"images: debootstrap {BASE_SUITE} (minbase + {', '.join(BASE_INCLUDE)})")
    run(["debootstrap", "--variant=minbase", f"--include={','.join(BASE_INCLUDE)}",
         BASE_SUITE, str(rootfs), _mirror()], timeout=1200)  # fmt: skip
    for rel in SLIM:
        target = rootfs / rel
        if target.is_dir():
            shutil.rmtree(target)
            target.mkdir(parents=True)
    _pack_rootfs(rootfs, BASE_REF, out, ["--config.env", "LANG=C.UTF-8",
                                         "--config.cmd", "python3"])  # fmt: skip
    shutil.rmtree(rootfs, ignore_errors=True)
    log(f"images: base {out.name} in {time.monotonic() - t0:.0f}s ({_mib(out)} MiB)")
    return out


def pause_archive() -> Path:
    """containerd's sandbox image, from Kubernetes' own pause.c (no registry pull ever)."""
    v = load_versions()
    kv = v["K8S_VERSION"]
    go = GoToolchain.find(v)
    kubernetes = Path(go.download(f"k8s.io/kubernetes@v{kv}")["Dir"])
    source = kubernetes / "build" / "pause" / "linux" / "pause.c"
    key = _sha(source.read_bytes(), PAUSE_REF)
    out = _cached("pause", key)
    if out.exists():
        return out
    install_debian_packages(IMAGE_PACKAGES)
    rootfs = IMAGES_DIR / f"pause-{key}.rootfs"
    shutil.rmtree(rootfs, ignore_errors=True)
    rootfs.mkdir(parents=True)
    run(["gcc", "-Os", "-static", "-DVERSION=v3.10", "-o", str(rootfs / "pause"), str(source)])
    _pack_rootfs(rootfs, PAUSE_REF, out, ["--config.entrypoint", "/pause",
                                          "--config.user", "65535:65535"])  # fmt: skip
    shutil.rmtree(rootfs, ignore_errors=True)
    return out


def busybox_archive() -> Path:
    """Debian's static busybox with the applets the smoke tests use."""
    binary = Path("/bin/busybox")
    install_debian_packages(("busybox-static",))
    key = _sha(binary.read_bytes(), BUSYBOX_REF)
    out = _cached("busybox", key)
    if out.exists():
        return out
    install_debian_packages(IMAGE_PACKAGES)
    rootfs = IMAGES_DIR / f"busybox-{key}.rootfs"
    shutil.rmtree(rootfs, ignore_errors=True)
    (rootfs / "bin").mkdir(parents=True)
    (rootfs / "tmp").mkdir()
    shutil.copy2(binary, rootfs / "bin" / "busybox")
    for applet in ("sh", "ls", "cat", "sleep", "nc", "ping", "echo", "date", "wc", "head",
                   "tail", "dd", "hostname", "ip", "true", "false", "env"):  # fmt: skip
        (rootfs / "bin" / applet).symlink_to("busybox")
    _pack_rootfs(rootfs, BUSYBOX_REF, out, ["--config.cmd", "sh"])
    shutil.rmtree(rootfs, ignore_errors=True)
    return out


def _copy_sources(dockerfile: Path) -> list[str]:
    """The context paths a Dockerfile's COPY/ADD lines read (not COPY --from=stage)."""
    sources: list[str] = []
    text = dockerfile.read_text().replace("\\\n", " ")
    for line in text.splitlines():
        words = line.split()
        if not words or words[0].upper() not in ("COPY", "ADD"):
            continue
        args = [w for w in words[1:] if not w.startswith("--")]
        if any(w.startswith("--from") for w in words[1:]):
            continue
        if args and args[0].startswith("["):
            args = json.loads(" ".join(args))
        sources += args[:-1]
    return sources


def _matches(rel: str, pattern: str) -> bool:
    if pattern.startswith("**/"):
        sub = pattern[3:]
        return any(fnmatch.fnmatch(part, sub) for part in rel.split("/"))
    return fnmatch.fnmatch(rel, pattern) or rel.startswith(pattern + "/")


def _ignored(rel: str, patterns: list[str]) -> bool:
    """.dockerignore semantics: the last pattern that matches decides; `!` re-includes."""
    ignored = False
    for raw in patterns:
        negate = raw.startswith("!")
        if _matches(rel, raw.lstrip("!").rstrip("/")):
            ignored = not negate
    return ignored


def _context_files(recipe: Recipe) -> Iterator[Path]:
    ignore_file = REPO_ROOT / ".dockerignore"
    patterns = []
    if ignore_file.exists():
        patterns = [p.strip() for p in ignore_file.read_text().splitlines()
                    if p.strip() and not p.startswith("#")]  # fmt: skip
    for src in _copy_sources(recipe.path):
        root = REPO_ROOT / src
        paths = sorted(root.rglob("*")) if root.is_dir() else sorted(REPO_ROOT.glob(src))
        for p in paths:
            rel = str(p.relative_to(REPO_ROOT))
            if p.is_file() and not _ignored(rel, patterns) and "__pycache__" not in p.parts:
                yield p


def recipe_key(recipe: Recipe, base: Path) -> str:
    """Changes when the Dockerfile, a file it copies, the base or a build argument changes."""
    parts: list[bytes | str] = [recipe.path.read_bytes(), base.name, json.dumps(recipe.build_args)]
    for p in _context_files(recipe):
        parts += [str(p.relative_to(REPO_ROOT)), p.read_bytes()]
    return _sha(*parts)


def build(recipe: Recipe) -> Path:
    """The recipe's image as a docker-archive (built with buildah unless cached)."""
    if not recipe.path.exists():
        raise HarnessError(f"{recipe.name}: no Dockerfile at {recipe.path}")
    base = base_archive()
    key = recipe_key(recipe, base)
    out = _cached(recipe.name, key)
    if out.exists():
        return out
    install_debian_packages(IMAGE_PACKAGES)
    t0 = time.monotonic()
    store = IMAGES_DIR / "buildah"
    buildah = ["buildah", "--root", str(store / "root"), "--runroot", str(store / "run"),
               "--storage-driver", "overlay"]  # fmt: skip
    args = {"PYTHON_IMAGE": f"docker-archive:{base}", **recipe.build_args}
    # RUN steps reach PyPI through whatever this host trusts (a proxy's CA, a pip.conf):
    # lend them the host's CA bundle and pip config for the build only (never in a layer).
    lent = [f for f in HOST_TRUST if Path(f).is_file()]
    log(f"images: building {recipe.ref} from {recipe.dockerfile}")
    run([*buildah, "bud", "--isolation", "chroot", "--layers=false", "--pull=never",
         *[a for k, v in args.items() for a in ("--build-arg", f"{k}={v}")],
         *[a for f in lent for a in ("--volume", f"{f}:{f}:ro")],
         "-f", str(recipe.path), "-t", recipe.ref, str(REPO_ROOT)],
        timeout=1800, log_file=IMAGES_DIR / f"{recipe.name}.build.log")  # fmt: skip
    tmp = out.with_suffix(".tmp")
    tmp.unlink(missing_ok=True)
    run([*buildah, "push", "--quiet", recipe.ref, f"docker-archive:{tmp}:{recipe.ref}"])
    tmp.replace(out)
    run([*buildah, "rmi", "--all", "--force"])  # the archive is the cache; keep no copies
    log(f"images: {recipe.ref} in {time.monotonic() - t0:.0f}s ({_mib(out)} MiB)")
    return out


def _mib(path: Path) -> int:
    return path.stat().st_size // 2**20


def archive_ref(archive: Path) -> str:
    """The tag a docker-archive carries (its manifest.json's first RepoTags entry)."""
    with tarfile.open(archive) as tar:
        member = tar.extractfile("manifest.json")
        assert member is not None
        tags: list[str] = json.load(member)[0]["RepoTags"]
    return tags[0]


def bed_archives() -> list[Path]:
    """What every real node gets: the sandbox image first, then the smoke-test and the
    project's images (those whose Dockerfile exists)."""
    archives = [pause_archive(), busybox_archive()]
    archives += [build(r) for r in RECIPES if r.path.exists()]
    _prune({a.name for a in archives} | {base_archive().name})
    return archives


def cloud_archives() -> list[Path]:
    """What the cloud's real node gets: the sandbox image and the workload's (a cloud instance
    runs the module and its relay sidecar, both from the workload image)."""
    (workload,) = [r for r in RECIPES if r.name == "ros2-module"]
    return [pause_archive(), build(workload)]


def _prune(keep: set[str]) -> None:
    """Drop archives of older recipes (one version of each image stays cached)."""
    for path in IMAGES_DIR.glob("*.tar"):
        if path.name not in keep:
            path.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="images.py", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("build", help="build (or reuse) the base, pause, busybox and the images")
    b.add_argument("--only", choices=[r.name for r in RECIPES])
    sub.add_parser("list", help="the cached archives")
    ns = parser.parse_args(argv)
    if ns.cmd == "build":
        t0 = time.monotonic()
        paths = [build(r) for r in RECIPES if r.name == ns.only] if ns.only else bed_archives()
        for p in paths:
            print(f"{archive_ref(p):45} {_mib(p):5} MiB  {p}")
        log(f"images ready in {time.monotonic() - t0:.0f}s")
        return 0
    for p in sorted(IMAGES_DIR.glob("*.tar")):
        print(f"{archive_ref(p):45} {_mib(p):5} MiB  {p}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except HarnessError as exc:
        print(f"images: error: {exc}", file=sys.stderr)
        sys.exit(1)
