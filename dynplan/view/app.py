"""The Foxglove Studio app that `flows.view` serves: pinned npm packages, fetched once into a cache folder.

The last open-source Foxglove Studio (`@foxglove/studio-base`, MPL-2.0) ships a prebuilt bundle of the app
(`assets/`); React 17 and react-dom 17 are its externals. `install` fetches the three tarballs with `npm pack`,
checks each against its pinned integrity (sha512, as the registry publishes it), keeps the app's files without
their inline source maps (71 MB of the bundle's 167 MB stay) and the React builds, and moves the result into the
cache in one rename, with a manifest of every file's size: a folder is either the whole app or absent.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import shutil
import subprocess
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

from dynplan.cli import InputError
from dynplan.files import exclusive


@dataclass(frozen=True)
class NpmPackage:
    """A pinned npm tarball and the members of it the app needs (tar member name → path in the app folder)."""

    name: str
    version: str
    integrity: str
    members: tuple[tuple[str, str], ...] = ()
    assets: bool = False  # also every `package/assets/…` file but source maps

    @property
    def spec(self) -> str:
        return f"{self.name}@{self.version}"


STUDIO_VERSION = "1.48.0"
PACKAGES = (
    NpmPackage(
        "@foxglove/studio-base",
        STUDIO_VERSION,
        "sha512-EY8cYoHUm6VyTSVZBdfn5EJK2bRwTfAjH92H5wgAEcnKyeCUyKkxjgwbqO2jKwRJGa+7VPaEHHF167BzFh+N4A==",
        (("package/package.json", "studio-base.package.json"),),
        assets=True,
    ),
    NpmPackage(
        "react",
        "17.0.2",
        "sha512-gnhPt75i/dq/z3/6q/0asP78D0u592D5L1pd7M8P+dck6Fu/jJeL6iVVK23fptSUZj8Vjf++7wXA8UNclGQcbA==",
        (("package/umd/react.production.min.js", "react.production.min.js"), ("package/LICENSE", "LICENSE.react")),
    ),
    NpmPackage(
        "react-dom",
        "17.0.2",
        "sha512-s4h96KtLDUQlsENhMn1ar8t2bEa+q/YAtj8pPPdIjPDGBDIVNsrD9aXNWqspUe6AzKCIG0C1HZZLqLV7qpOBGA==",
        (
            ("package/umd/react-dom.production.min.js", "react-dom.production.min.js"),
            ("package/LICENSE", "LICENSE.react-dom"),
        ),
    ),
)
#: The app folder's name in the cache: the pinned version, so that another pin installs beside it.
APP_FOLDER = f"foxglove-studio-{STUDIO_VERSION}"
MANIFEST = "manifest.json"
_SOURCE_MAP = re.compile(rb"\n?//# sourceMappingURL=data:[^\n]*")


def default_cache() -> Path:
    """`$DYNPLAN_VIEWER_CACHE`, else `$XDG_CACHE_HOME/dynplan/viewer` (`~/.cache/dynplan/viewer`)."""
    if os.environ.get("DYNPLAN_VIEWER_CACHE"):
        return Path(os.environ["DYNPLAN_VIEWER_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dynplan" / "viewer"


def installed_app(cache: Path) -> Path | None:
    """The installed app folder in `cache`, or None where it is absent or incomplete (a file missing or resized)."""
    folder = Path(cache) / APP_FOLDER
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        complete = all((folder / name).stat().st_size == size for name, size in manifest["files"].items())
        confined = all(_inside(folder, name) for name in manifest["files"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return folder if complete and confined and manifest.get("version") == STUDIO_VERSION else None


def app_files(folder: Path) -> dict[str, Path]:
    """The installed app's files by their path in the app folder (what the server may serve of it); a manifest that
    names a file outside the folder (`..`, an absolute path, a link leading out) is an InputError naming it."""
    names = json.loads((folder / MANIFEST).read_text())["files"]
    for name in names:
        if not _inside(folder, name):
            raise InputError(f"{folder / MANIFEST}: names {name!r}, outside the app's folder; remove {folder}")
    return {name: folder / name for name in names}


def _inside(folder: Path, name: str) -> bool:
    """Whether `name` resolves (links followed) to a file inside `folder`."""
    root = folder.resolve()
    return root in (root / name).resolve().parents


def install(cache: Path) -> Path:
    """Fetch, check and unpack the pinned app into `cache` (nothing to do where it is installed); returns its folder.
    An InputError names what is missing (npm) or wrong (a tarball whose digest is not the pinned one). Installs into
    one cache take turns (a lock file), and what an interrupted one left is removed by the next."""
    if (found := installed_app(cache)) is not None:
        return found
    npm = shutil.which("npm")
    if npm is None:
        raise InputError(
            "npm not found: the viewer fetches Foxglove Studio from the npm registry with it "
            "(Debian: apt-get install npm)"
        )
    with exclusive(cache / ".install.lock", waiting="waiting for another install of the viewer's app"):
        if (found := installed_app(cache)) is not None:  # another install finished while this one waited
            return found
        for stale in cache.glob(".install-*"):
            shutil.rmtree(stale, ignore_errors=True)
        return _install(npm, cache)


def _install(npm: str, cache: Path) -> Path:
    with tempfile.TemporaryDirectory(prefix=".install-", dir=cache) as work:
        work = Path(work)
        print(
            f"fetching Foxglove Studio {STUDIO_VERSION} and React 17 from the npm registry (37 MB, once) into {cache}"
        )
        tarballs = _pack(npm, work)
        app = work / APP_FOLDER
        files: dict[str, int] = {}
        for package, tarball in zip(PACKAGES, tarballs, strict=True):
            _check_integrity(package, tarball)
            files |= _unpack(package, tarball, app)
        (app / MANIFEST).write_text(json.dumps({"version": STUDIO_VERSION, "files": files}, indent=1))
        target = cache / APP_FOLDER
        shutil.rmtree(target, ignore_errors=True)  # an incomplete earlier install
        os.replace(app, target)
    print(f"installed {len(files)} files ({sum(files.values()) / 1e6:.0f} MB) in {target}")
    return target


def _pack(npm: str, work: Path) -> list[Path]:
    """`npm pack` the pinned packages into `work`; their tarballs in PACKAGES' order."""
    command = [npm, "pack", "--json", "--ignore-scripts", "--pack-destination", str(work), *(p.spec for p in PACKAGES)]
    done = subprocess.run(command, capture_output=True, text=True, cwd=work, timeout=600)
    if done.returncode != 0:
        detail = (done.stderr.strip().splitlines() or ["no message"])[-1]
        raise InputError(f"npm pack {' '.join(p.spec for p in PACKAGES)} failed: {detail}")
    packed = {(entry["name"], entry["version"]): work / entry["filename"] for entry in json.loads(done.stdout)}
    return [packed[(p.name, p.version)] for p in PACKAGES]


def _check_integrity(package: NpmPackage, tarball: Path) -> None:
    digest = hashlib.sha512(tarball.read_bytes()).digest()
    found = "sha512-" + base64.b64encode(digest).decode()
    if found != package.integrity:
        raise InputError(f"{tarball.name}: its sha512 is {found}, not the pinned {package.integrity} of {package.spec}")


def _unpack(package: NpmPackage, tarball: Path, app: Path) -> dict[str, int]:
    """Write the members the app needs into `app`, source maps dropped; their sizes by app path."""
    wanted = dict(package.members)
    sizes = {}
    with tarfile.open(tarball) as archive:
        for member in archive.getmembers():
            name = wanted.get(member.name)
            if name is None and package.assets and member.name.startswith("package/assets/"):
                name = member.name.removeprefix("package/")
            if name is None or not member.isfile() or name.endswith(".map"):
                continue
            data = archive.extractfile(member).read()
            if name.endswith(".js"):
                data = _SOURCE_MAP.sub(b"", data)
            (app / name).parent.mkdir(parents=True, exist_ok=True)
            (app / name).write_bytes(data)
            sizes[name] = len(data)
    return sizes
