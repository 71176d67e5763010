"""The vocabularies of the tool, one registry each (docs/design.md §1).

A vocabulary is defined once, here, and every other module derives from it: the plans
(:mod:`.plans`), the candidate effects of the discrepancy loop (:mod:`.effects`), the
parameters and their units (:mod:`.units`) and the constants of the IMU node that the
numerics and the files share (:mod:`.constants`). The device objects sit with the client,
in :mod:`canimucal.device.objects`. Pure data and pure numpy functions only.
"""
