"""The motion core: numpy only. Skeletons, HumanML3D features, BVH, retargeting, IK and glTF.

Every other package speaks this package's language; it imports nothing of ours.
"""
