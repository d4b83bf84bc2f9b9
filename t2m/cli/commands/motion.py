"""`t2m motion joints|features|from-bvh`: convert between HumanML3D features, joint positions and BVH files."""
from __future__ import annotations

import argparse
from pathlib import Path

JOINT_MAP_NAMES = ("bandai-namco",)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("motion", help="convert features <-> joints, BVH -> joints")
    commands = parser.add_subparsers(dest="motion_command", metavar="ACTION")
    parser.set_defaults(func=lambda args: _usage(parser))

    joints = commands.add_parser("joints", help="HumanML3D features [T, D] -> joint positions [T, J, 3]")
    joints.add_argument("features", type=Path, help="features .npy ([T, 263] for smpl22, [T, 251] for kit21)")
    joints.add_argument("-o", "--output", type=Path, required=True, help="joints .npy to write")
    joints.add_argument("--skeleton", choices=("smpl22", "kit21"), default="smpl22")
    joints.set_defaults(func=_features_to_joints)

    features = commands.add_parser("features", help="joint positions [T, J, 3] -> HumanML3D features [T-1, D]")
    features.add_argument("joints", type=Path, help="joints .npy [T, J, 3], metres, Y up")
    features.add_argument("-o", "--output", type=Path, required=True, help="features .npy to write")
    features.add_argument("--skeleton", choices=("smpl22", "kit21"), default="smpl22")
    features.add_argument("--no-normalize", action="store_true",
                          help="the joints are already HumanML3D-normalised (skip bone lengths/floor/origin/facing)")
    features.set_defaults(func=_joints_to_features)

    from_bvh = commands.add_parser("from-bvh", help="BVH file -> SMPL-22 joints [T, 22, 3] (metres, normalised)")
    from_bvh.add_argument("bvh", type=Path, help="BVH file")
    from_bvh.add_argument("--map", choices=JOINT_MAP_NAMES, default="bandai-namco", help="source skeleton's joint map")
    from_bvh.add_argument("--fps", type=float, default=20.0, help="output frame rate (default 20)")
    from_bvh.add_argument("-o", "--output", type=Path, required=True, help="joints .npy to write")
    from_bvh.set_defaults(func=_bvh_to_joints)


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _load_npy(path: Path, what: str):
    import numpy as np

    from t2m.cli.main import CliError

    if path.suffix.lower() != ".npy":
        raise CliError(f"{path}: expected a .npy file of {what}")
    if not path.is_file():
        raise FileNotFoundError(2, "No such file", str(path))
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as error:
        raise CliError(f"{path}: not a readable .npy file ({error})") from None


def _save_npy(path: Path, array) -> None:
    import numpy as np

    from t2m.cli.main import CliError

    if path.suffix.lower() != ".npy":
        raise CliError(f"{path}: the output must be a .npy file")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, array)


def _features_to_joints(args: argparse.Namespace) -> int:
    from t2m.motion.features import features_to_joints
    from t2m.motion.skeleton import get_skeleton

    features = _load_npy(args.features, "features")
    try:
        joints = features_to_joints(features, get_skeleton(args.skeleton))
    except ValueError as error:
        raise ValueError(f"{args.features}: {error}") from None
    _save_npy(args.output, joints)
    print(f"wrote {args.output}: joints {joints.shape}")
    return 0


def _joints_to_features(args: argparse.Namespace) -> int:
    from t2m.motion.features import joints_to_features, normalize_joints
    from t2m.motion.skeleton import get_skeleton

    skeleton = get_skeleton(args.skeleton)
    joints = _load_npy(args.joints, "joints")
    try:
        if not args.no_normalize:
            joints = normalize_joints(joints, skeleton)
        features = joints_to_features(joints, skeleton)
    except ValueError as error:
        raise ValueError(f"{args.joints}: {error}") from None
    _save_npy(args.output, features)
    print(f"wrote {args.output}: features {features.shape}")
    return 0


def _bvh_to_joints(args: argparse.Namespace) -> int:
    from t2m.cli.main import CliError
    from t2m.motion.bvh import read_bvh
    from t2m.motion.retarget import BANDAI_NAMCO, bvh_to_smpl22

    if not args.fps > 0:
        raise CliError(f"--fps must be positive, got {args.fps}")
    if not args.bvh.is_file():
        raise FileNotFoundError(2, "No such file", str(args.bvh))
    joint_map = {"bandai-namco": BANDAI_NAMCO}[args.map]
    try:
        joints = bvh_to_smpl22(read_bvh(args.bvh), joint_map, target_fps=args.fps)
    except ValueError as error:
        message = str(error)
        raise ValueError(message if str(args.bvh) in message else f"{args.bvh}: {message}") from None
    _save_npy(args.output, joints)
    print(f"wrote {args.output}: joints {joints.shape} at {args.fps:g} fps")
    return 0
