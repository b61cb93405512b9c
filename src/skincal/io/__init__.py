"""File I/O every layer may use (it imports only :mod:`skincal.errors`): guarded JSON/YAML readers
(:mod:`skincal.io.jsonio`) and atomic writes (:mod:`skincal.io.atomic`).

It sits below :mod:`skincal.kinematics`, so reading a chain file or writing a protocol loads neither
``h5py`` nor any other part of :mod:`skincal.data`.
"""
