"""The compile stage, between the checked scene (scene/, bodies/) and what runs it (engine/, equations/, fmu/).

A normalized scene becomes, once and at build time:
  model.py           its structure: bodies parents first, coordinate indices, what is structurally zero, the
                     parameters bound (the Model the numpy reference evaluates, Pinocchio's Model/Data split)
  variables.py       its FMU variables: names, value references, kinds, units, nominals (both FMI versions)
  elastic_tables.py  the elastic bodies' invariants and stress modes as the engine's sections
  scene_file.py      the compiled scene: the bytes the C engine loads (mbs_layout.h's layout)
Nothing here runs per step.
"""
