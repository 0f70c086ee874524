"""Where a task's MuJoCo model comes from: an MJCF file, or a robot of MuJoCo Menagerie loaded
by name through the `mujoco-menagerie` package, which downloads the robot's folder once into its
cache (`MENAGERIE_CACHE_DIR`, default `~/.cache/mujoco_menagerie` on Linux) or reads an offline
copy of Menagerie's folders (`MENAGERIE_ROOT`). Either way the task gets an `MjSpec` to edit
before it compiles it. `describe` is what a run records of its model, `about` what `lab info`
and `lab config show` say of one: both from the package's registry, without downloading, and
without MuJoCo (imported only to load a model)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from labcli import files
from labcli.envs.spec import Menagerie
from labcli.errors import LabError, first_line

if TYPE_CHECKING:
    import mujoco
    import mujoco_menagerie as mm
    from rich.console import Console
    from rich.progress import Progress

ModelSource = Path | Menagerie

OFFLINE_HINT = ("connect to the internet once, so that it downloads into the cache "
                "(MENAGERIE_CACHE_DIR), or point MENAGERIE_ROOT at a copy of Menagerie's "
                "robot folders")
CACHE_HINT = ("set MENAGERIE_CACHE_DIR to a writable folder, or point MENAGERIE_ROOT at a copy "
              "of Menagerie's robot folders")


def load_spec(source: ModelSource) -> mujoco.MjSpec:
    """The model as an editable `MjSpec`; a LabError (one line, the ways out) where a
    Menagerie robot can be neither found nor downloaded."""
    import mujoco

    path = menagerie_xml(source) if isinstance(source, Menagerie) else source
    try:
        return mujoco.MjSpec.from_file(str(path))
    except (ValueError, FileNotFoundError) as exc:
        hint = ("reinstall the task's package" if not isinstance(source, Menagerie) else
                f"delete {path.parent} to download it again, or fix the copy MENAGERIE_ROOT "
                "points at")
        raise LabError(f"the model {path} does not load: {first_line(exc)}", hint) from None


def set_options(model: mujoco.MjModel, cfg: Any) -> None:
    """The config's physics options, where it sets them, over the MJCF's: the step
    (`sim_dt`), the solver's, its line search's and the noslip solver's iterations, the
    friction cones, impratio and the integrator."""
    import mujoco

    enums = {"cone": (mujoco.mjtCone, "mjCONE_"), "integrator": (mujoco.mjtIntegrator, "mjINT_")}
    for key, field in (("sim_dt", "timestep"), ("solver_iterations", "iterations"),
                       ("ls_iterations", "ls_iterations"), ("cone", "cone"),
                       ("noslip_iterations", "noslip_iterations"), ("impratio", "impratio"),
                       ("integrator", "integrator")):
        value = getattr(cfg, key, None)
        if key in enums and value is not None:
            enum, prefix = enums[key]
            value = getattr(enum, prefix + value.upper())
        if value is not None:
            setattr(model.opt, field, value)


def drop_visual_meshes(spec: mujoco.MjSpec) -> None:
    """Make the model's visual-only mesh geoms (no collisions, no contact pair, no part in
    their body's inertia) tiny spheres, delete the meshes no geom uses any more and the
    textures: the physics
    is the same, the model a fraction of the size (Menagerie's G1: 72 MiB with its meshes), which
    counts where every env has its own copy (the cpu backend's per-env fields). Geoms keep their
    ids, so a renderer's model with the meshes shows the same state."""
    import mujoco

    paired = {name for pair in spec.pairs for name in (pair.geomname1, pair.geomname2)}
    for geom in spec.geoms:
        body = geom.parent
        if (geom.type == mujoco.mjtGeom.mjGEOM_MESH and geom.contype == 0
                and geom.conaffinity == 0 and geom.name not in paired
                and (geom.density == 0 or getattr(body, "explicitinertial", False))):
            geom.type, geom.meshname = mujoco.mjtGeom.mjGEOM_SPHERE, ""
            geom.size = [1e-3, 0.0, 0.0]
    used = {geom.meshname for geom in spec.geoms if geom.type == mujoco.mjtGeom.mjGEOM_MESH}
    for mesh in list(spec.meshes):
        if mesh.name not in used:
            spec.delete(mesh)
    # Textures (a skybox: 4.7 MB) are only ever drawn.
    for material in spec.materials:
        material.textures = [""] * len(material.textures)
    for texture in list(spec.textures):
        spec.delete(texture)


def menagerie_xml(source: Menagerie) -> Path:
    """The entry point's MJCF on disk, the robot's folder downloaded first if need be (with its
    progress on stderr)."""
    import mujoco_menagerie as mm

    robot, entry = _lookup(source)
    cache = mm.Cache()
    if cache.root is not None and not (cache.root / robot.name).is_dir():
        raise LabError(f"MENAGERIE_ROOT={cache.root} has no folder {robot.name} (MuJoCo "
                       f"Menagerie's {robot.display_name})",
                       f"copy Menagerie's {robot.name} folder there, or unset MENAGERIE_ROOT so "
                       "that it downloads once into the cache (MENAGERIE_CACHE_DIR)")
    try:
        if cache.root is None and not cache.is_cached(robot):
            _check_writable(cache.dir)
            with DownloadProgress(robot, cache) as progress:
                folder = robot.path(cache, progress=progress)
        else:
            folder = robot.path(cache, progress=None)
    except mm.DownloadError as exc:
        raise LabError(f"MuJoCo Menagerie's {robot.name} is not in the cache {cache.dir} and "
                       f"could not be downloaded: {first_line(exc)}", OFFLINE_HINT) from None
    except mm.MenagerieError as exc:
        raise LabError(f"MuJoCo Menagerie's {robot.name} could not be loaded: "
                       f"{first_line(exc)}", OFFLINE_HINT) from None
    except OSError as exc:  # the cache cannot be made or written (network errors are above)
        raise LabError(f"MuJoCo Menagerie's cache {cache.dir} cannot be written: "
                       f"{exc.strerror or first_line(exc)}", CACHE_HINT) from None
    path = folder / entry.file
    if not path.is_file():
        raise LabError(f"MuJoCo Menagerie's {robot.name} has no {entry.file} in {folder}",
                       f"point MENAGERIE_ROOT at a complete copy of {robot.name}'s folder")
    return path


def _check_writable(folder: Path) -> None:
    """Fail before a download where the cache cannot take it: by trying, as permission bits do
    not tell read-only mounts, and root ignores them."""
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryFile(dir=folder):
        pass


def _lookup(source: Menagerie) -> tuple[mm.Robot, mm.EntryPoint]:
    """The robot and entry point a `Menagerie` names, from the package's registry (no I/O)."""
    import mujoco_menagerie as mm

    try:
        robot = mm.get(source.robot)
    except mm.UnknownRobotError as exc:
        close = f"did you mean '{exc.suggestions[0]}'? " if exc.suggestions else ""
        raise LabError(f"MuJoCo Menagerie has no robot '{source.robot}'",
                       f"{close}`python -m mujoco_menagerie names` lists its robots") from None
    try:
        return robot, robot.entry(source.entry)
    except mm.UnknownEntryPointError:
        raise LabError(f"MuJoCo Menagerie's {robot.name} has no entry '{source.entry}'",
                       f"its entries: {', '.join(robot.entry_names)}") from None


def describe(source: ModelSource) -> dict[str, Any]:
    """What a run records of its model, so that `lab play` of it later finds the same one: a
    file's path and sha256 (of that file, not of the files it includes); a Menagerie robot's
    name, entry, the package's version, the Menagerie commit its registry names and the robot
    folder's tree id (and the offline copy it read)."""
    if not isinstance(source, Menagerie):
        return {"file": str(source), "sha256": files.sha256(source)}
    import mujoco_menagerie as mm

    robot, _ = _lookup(source)
    described = {"robot": source.robot, "entry": source.entry, "package": mm.__version__,
                 "commit": mm.commit(), "tree": robot.oid}
    root = mm.Cache().root
    if root is not None:
        described["root"] = str(root)
    return {"menagerie": described}


def changed_since(source: Menagerie, tree: str | None, package: str | None) -> str | None:
    """One line where the installed registry's folder of `source`'s robot is not the one a run
    recorded (its git tree id `tree`, in mujoco-menagerie `package`); None where it is, or
    where the run recorded none."""
    import mujoco_menagerie as mm

    try:
        now = mm.get(source.robot).oid
    except mm.MenagerieError:
        return None  # loading it says so
    if tree is None or now == tree:
        return None
    return (f"MuJoCo Menagerie's {source.robot} may have changed since the run recorded it: "
            f"its folder was {tree[:12]} (mujoco-menagerie {package or '?'}) and is "
            f"{now[:12]} here ({mm.__version__}); the policy may act differently")


def about(source: ModelSource) -> dict[str, str]:
    """What `lab info` says of a model, as name → value, without downloading it: a file's
    path; a Menagerie robot and entry, the package's version and where its files are read
    from (MENAGERIE_ROOT, the cache, or a download on first use)."""
    if not isinstance(source, Menagerie):
        return {"model": str(source)}
    import mujoco_menagerie as mm

    robot, entry = _lookup(source)
    cache = mm.Cache()
    if cache.root is not None:
        folder = cache.root / robot.name
        files = (f"{folder} (MENAGERIE_ROOT)" if folder.is_dir() else
                 f"none: MENAGERIE_ROOT={cache.root} has no folder {robot.name}")
    elif cache.is_cached(robot):
        files = f"{cache.model_path(robot)} (cached)"
    else:
        size = f"{mebibytes(robot.download_size)} " if robot.download_size else ""
        files = f"not cached yet: a {size}download into {cache.dir} on first use"
    return {"model": f"MuJoCo Menagerie's {robot.name} ({robot.display_name}), entry "
                     f"{entry.name} ({entry.file})",
            "model version": version(mm.__version__, mm.commit(), robot.name, robot.oid),
            "model files": files}


def version(package: str | None, commit: str | None, robot: str, tree: str | None) -> str:
    """A Menagerie model's version: the package's, the Menagerie commit its registry names, the
    robot folder's git tree id."""
    return (f"mujoco-menagerie {package or '?'}: Menagerie commit {(commit or '?')[:12]}, "
            f"{robot} folder {(tree or '?')[:12]}")


def about_line(source: ModelSource) -> str:
    """`about` in one line."""
    parts = about(source)
    if "model files" in parts:
        parts["model files"] = f"files {parts['model files']}"
    return "; ".join(parts.values())


def mebibytes(size: int) -> str:
    return f"{size / 2**20:.1f} MiB"


class DownloadProgress:
    """A robot's download on stderr, shown once however many times the package retries: a
    transient rich bar (MiB done of the total) on a terminal; elsewhere (CI logs) one line when
    it starts and one when it ends. The package calls it with `(name, done, total)`."""

    def __init__(self, robot: mm.Robot, cache: mm.Cache, console: Console | None = None):
        from rich.console import Console

        self.robot, self.cache = robot, cache
        self.console = console or Console(stderr=True, markup=False, highlight=False)
        self._bar: Progress | None = None

    def __enter__(self) -> DownloadProgress:
        name, size = self.robot.name, self.robot.download_size
        if self.console.is_terminal:
            from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn

            self._bar = Progress(TextColumn(f"downloading MuJoCo Menagerie's {name}"),
                                 BarColumn(), DownloadColumn(binary_units=True),
                                 console=self.console, transient=True)
            self._bar.start()
            self._task = self._bar.add_task(name, total=size)
        else:
            of = f" ({mebibytes(size)})" if size else ""
            self.console.print(f"downloading MuJoCo Menagerie's {name}{of} from "
                               f"{self.cache.base_url} into {self.cache.dir}", soft_wrap=True)
        return self

    def __call__(self, name: str, done: int, total: int) -> None:
        if self._bar is not None:
            self._bar.update(self._task, completed=done, total=total or self.robot.download_size)

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if self._bar is not None:
            self._bar.stop()
        elif kind is None:
            self.console.print(f"downloaded MuJoCo Menagerie's {self.robot.name} into "
                               f"{self.cache.model_path(self.robot)}", soft_wrap=True)
