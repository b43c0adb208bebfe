"""The FMU exporter's C sources and FMI 2.0 headers (data: compiled at export time by
:mod:`nmsid.export.fmu.build`, never imported). A package of its own so that setuptools
installs the files as package data without its "Package would be ignored" warning."""
