"""The FMU's ``modelDescription.xml`` and the C header ``twin_data.h``, both from the one
variable table of :mod:`nmsid.export.fmu.variables`.

FMI 2.0.x section 2.2 (schema ``fmi2ModelDescription.xsd``): one description for model
exchange and co-simulation; ``ModelStructure`` lists outputs, state derivatives and initial
unknowns by their 1-based index among the ScalarVariables.
"""

from __future__ import annotations

import datetime as _dt
from xml.sax.saxutils import quoteattr

from nmsid.export.fmu.variables import STATE_NAMES, Var, value_references

# name -> SI base unit exponents (FMI 2.0.x section 2.2.2 BaseUnit)
_UNITS: dict[str, dict[str, float]] = {
    "N": {"kg": 1, "m": 1, "s": -2}, "N/s": {"kg": 1, "m": 1, "s": -3},
    "N/s2": {"kg": 1, "m": 1, "s": -4}, "rad/s": {"rad": 1, "s": -1}, "s": {"s": 1},
    "1": {}, "%": {"factor": 0.01},
    # a torque joint's twin (docs/joints.md): N m = kg m2 s-2
    "N.m": {"kg": 1, "m": 2, "s": -2}, "N.m/s": {"kg": 1, "m": 2, "s": -3},
    "N.m/s2": {"kg": 1, "m": 2, "s": -4},
}


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def model_description(vs: list[Var], *, model_name: str, model_identifier: str, guid: str,
                      description: str, version: str, generation_tool: str,
                      annotation_xml: str, source_files: list[str]) -> str:
    """The model description as text (UTF-8 XML)."""
    index = {v.name: i + 1 for i, v in enumerate(vs)}
    vr = value_references(vs)
    when = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    units = sorted({v.unit for v in vs if v.unit})
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f'<fmiModelDescription fmiVersion="2.0" modelName={quoteattr(model_name)} '
           f'guid="{guid}" description={quoteattr(description)} '
           f'version={quoteattr(version)} generationTool={quoteattr(generation_tool)} '
           f'generationDateAndTime="{when}" variableNamingConvention="structured" '
           f'numberOfEventIndicators="0">']
    srcs = "".join(f'      <File name="{s}"/>\n' for s in source_files)
    for tag, extra in (("ModelExchange", ""),
                       ("CoSimulation", ' canHandleVariableCommunicationStepSize="true" '
                                        'canInterpolateInputs="true" '
                                        'maxOutputDerivativeOrder="0"')):
        out.append(f'  <{tag} modelIdentifier="{model_identifier}"{extra} '
                   'canGetAndSetFMUstate="true" canSerializeFMUstate="true" '
                   'canNotUseMemoryManagementFunctions="true">')
        out.append(f'    <SourceFiles>\n{srcs}    </SourceFiles>')
        out.append(f'  </{tag}>')
    out.append('  <UnitDefinitions>')
    for u in units:
        exps = _UNITS[u]
        attrs = " ".join(f'{k}="{v}"' for k, v in exps.items())
        out.append(f'    <Unit name="{u}"><BaseUnit {attrs}/></Unit>' if attrs
                   else f'    <Unit name="{u}"/>')
    out.append('  </UnitDefinitions>')
    out.append('  <LogCategories>\n    <Category name="logStatusError"/>\n  </LogCategories>')
    out.append('  <DefaultExperiment startTime="0.0" stopTime="15.0" stepSize="0.0005"/>')
    out.append('  <VendorAnnotations>')
    out.append(f'    <Tool name="nmsid">{annotation_xml}</Tool>')
    out.append('  </VendorAnnotations>')
    out.append('  <ModelVariables>')
    for v in vs:
        vattrs = [f'name={quoteattr(v.name)}', f'valueReference="{vr[v.name]}"',
                  f'description={quoteattr(v.description)}', f'causality="{v.causality}"',
                  f'variability="{v.variability}"']
        if v.initial:
            vattrs.append(f'initial="{v.initial}"')
        inner = []
        if v.unit and v.type == "Real":
            inner.append(f'unit="{v.unit}"')
        if v.derivative_of:
            inner.append(f'derivative="{index[v.derivative_of]}"')
        if v.start is not None:
            inner.append(f'start="{_fmt(v.start)}"')
        out.append(f'    <ScalarVariable {" ".join(vattrs)}>')
        out.append(f'      <{v.type} {" ".join(inner)}/>')
        out.append('    </ScalarVariable>')
    out.append('  </ModelVariables>')
    # per joint (one for a one-joint FMU), by each variable's one-joint name; the
    # Derivatives' order is the order of the continuous states (joint after joint)
    joints: dict[int, dict[str, int]] = {}
    for i, v in enumerate(vs):
        joints.setdefault(v.joint, {})[v.role] = i + 1
    outputs, ders_all, unknowns = [], [], []
    for _, at in sorted(joints.items()):
        states = [at[n] for n in STATE_NAMES]
        ders = [at[f"der({n})"] for n in STATE_NAMES]
        sE = at["sE"]
        outputs.append(f'      <Unknown index="{at["force_N"]}" '
                       f'dependencies="{states[1]} {states[4]} {states[6]} {sE}"/>')
        outputs += [f'      <Unknown index="{at[n]}" dependencies="{sE}"/>'
                    for n in ("Kp", "wn_rad_s", "zeta")]
        ders_all += ders
        unknowns += [at["force_N"], at["Kp"], at["wn_rad_s"], at["zeta"], *states, *ders]
    out.append('  <ModelStructure>')
    out.append('    <Outputs>')
    out += outputs
    out.append('    </Outputs>')
    out.append('    <Derivatives>')
    out += [f'      <Unknown index="{d}"/>' for d in ders_all]
    out.append('    </Derivatives>')
    out.append('    <InitialUnknowns>')
    unknowns = sorted(unknowns)
    out += [f'      <Unknown index="{u}"/>' for u in unknowns]
    out.append('    </InitialUnknowns>')
    out.append('  </ModelStructure>')
    out.append('</fmiModelDescription>')
    return "\n".join(out) + "\n"


def c_header(vs: list[Var], guid: str, joint_names: list[str]) -> str:
    """``twin_data.h``: a joint's value references (one joint's layout, the same for
    every joint: ``c/nmsid_model.h``), counts, each joint's start values and name, and
    the GUID."""
    per = [[v for v in vs if v.joint == k] for k in range(len(joint_names))]
    first = per[0]
    vr = value_references(first)
    lines = ["/* generated by nmsid (export/fmu/description.py): the twin's values */",
             "#ifndef NMSID_TWIN_DATA_H", "#define NMSID_TWIN_DATA_H",
             f'#define MODEL_GUID "{guid}"', f"#define N_JOINTS {len(joint_names)}",
             "static const char *const JOINT_NAMES[N_JOINTS] = {"
             + ", ".join(f'"{n}"' for n in joint_names) + "};"]
    prefix = {"Real": "VR_", "Integer": "VRI_", "Boolean": "VRB_"}
    for v in first:
        lines.append(f"#define {prefix[v.type]}{v.c_name} {vr[v.name]}")
    for t, n, ctype in (("Real", "N_REAL", "fmi2Real"), ("Integer", "N_INTEGER", "fmi2Integer"),
                        ("Boolean", "N_BOOLEAN", "fmi2Boolean")):
        rows = [[v for v in joint if v.type == t] for joint in per]
        if any([v.role for v in r] != [v.role for v in rows[0]] for r in rows):
            raise ValueError("every joint of an FMU has the same variables")
        lines.append(f"#define {n} {len(rows[0])}")
        vals = ", ".join("{" + ", ".join(_c_value(v) for v in r) + "}" for r in rows)
        lines.append(f"static const {ctype} START_{t.upper()}[N_JOINTS][{n}] = {{{vals}}};")
    lines.append("#endif")
    return "\n".join(lines) + "\n"


def _c_value(v: Var) -> str:
    if v.start is None:
        return "0"
    if isinstance(v.start, bool):
        return "1" if v.start else "0"
    if isinstance(v.start, int):
        return str(v.start)
    return repr(float(v.start))
