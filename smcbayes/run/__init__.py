"""The typed run directory: the only contract between the stages (see :mod:`.directory`)."""

from smcbayes.run.directory import IDENTITY_KEYS, RunDir, RunIdentity, StageState, read_json

__all__ = ["IDENTITY_KEYS", "RunDir", "RunIdentity", "StageState", "read_json"]
