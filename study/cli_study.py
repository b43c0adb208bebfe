"""``nmsid study STUDY.toml|FOLDER --out DIR``: placeholder until the study runner lands."""


def register(sub) -> None:
    pass
