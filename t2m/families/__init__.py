"""The model families t2m ships, one folder each (gpt/, hifigpt/, masked/, diffusion/): its declaration, its served
torch-free loop and its offline code (networks, training, export, importers, evaluation). Each folder's
`__init__` exposes one `t2m.bundle.family.ModelFamily` instance named FAMILY; the registry (t2m.bundle.family) finds
them by module name. A new family is one more such folder (or a plug-in package's entry point)."""
