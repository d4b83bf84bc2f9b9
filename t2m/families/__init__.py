"""The model families t2m ships, one module each (gpt.py, masked.py, hifigpt.py), each holding one
`t2m.bundle.family.ModelFamily` instance named FAMILY. The registry (t2m.bundle.family) finds them by module name;
nothing else in t2m imports them. A new family is one more such module (or a plug-in package's entry point)."""
