"""Fakes of the vendor libraries (see the package docstring of ``testing``)."""
