"""New hostile cases of the kinds in issue 12 that the first round of tests did not cover (an audit's second set).

Scene files: every case ends in `mbsfmu.load` as a ModelError with the file, a line, a key path and a hint, within
1 s CPU under a 1 GiB address-space limit (one worker process for all of them); the CLI prints one line and
exits non-zero. Hosts: both FMU kinds (pythonfmu through its loader shim, native) take hostile call sequences
through fmpy's FMU2Slave in child processes; checks are the FMI 2.0 rules and an untouched twin instance.
"""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from test_scene_hostile import BASE, ELASTIC, NODAL_BODY, base, bomb, chain, elastic, inline, nodal_arrays, run_bounded

CPU_SECONDS = 1.0
CPU_LARGE = {"star_10000_then_bad": 4.0}   # a 1.4 MB file: ~2 s of honest reading


# ---- makers of cases that need files beside the scene -----------------------------------------------------------
def _scene(d, text, name="scene.yaml"):
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_text(text)
    return d / name


def _bytes(data):
    def make(d):
        d.mkdir(parents=True, exist_ok=True)
        (d / "scene.yaml").write_bytes(data)
        return d / "scene.yaml"
    return make


def _npy(v):
    buf = io.BytesIO()
    np.save(buf, v, allow_pickle=False)
    return buf.getvalue()


def _npz(members, *, file="data.npz"):
    """An .npz of raw members {name: bytes} (a list of pairs: duplicates allowed) beside a scene reading it."""
    def make(d):
        d.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(d / "data.npz", "w") as z:
            for k, v in (members.items() if isinstance(members, dict) else members):
                z.writestr(k, v)
        return _scene(d, BASE + NODAL_BODY % f"{{file: {file}}}")
    return make


def _nodal(**changes):
    arrays = dict(nodal_arrays(), **changes)
    return {f"{k}.npy": (_npy(v) if not isinstance(v, bytes) else v) for k, v in arrays.items()}


def _header(shape, descr="<f8", tail=b""):
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + tail


def _symlink_loop(d):
    d.mkdir(parents=True)
    (d / "a.yaml").symlink_to(d / "b.yaml")
    (d / "b.yaml").symlink_to(d / "a.yaml")
    return d / "a.yaml"


def _npz_symlink_loop(d):
    d.mkdir(parents=True)
    (d / "a.npz").symlink_to(d / "b.npz")
    (d / "b.npz").symlink_to(d / "a.npz")
    return _scene(d, BASE + NODAL_BODY % "{file: a.npz}")


def _star(n, tail):
    lines = ["mbsfmu: 1", "name: star", "bodies:"]
    for i in range(n):
        lines += [f"  b{i}:", "    parent: world", "    joint: {type: revolute, axis: [0, 1, 0], at: [0, 0, -0.1]}",
                  "    mass: 1.0", "    center_of_mass: [0, 0, -0.05]"]
    return "\n".join(lines) + "\n" + tail


def _many(section, n, last):
    item = {"parameters": "  p{i}: {i}\n", "forces": "  - {{type: force, body: arm, value: [0, 0, 1]}}\n",
            "outputs": "  - {{body: arm, name: o{i}}}\n"}[section]
    body = "".join(item.format(i=i) for i in range(n))
    if section == "parameters":
        return base("  L: 1.0", "  L: 1.0\n" + body + last)
    return BASE + f"{section}:\n" + body + last


D = lambda e: base("coordinates: [phi]}", "coordinates: [phi], drive: {phi: '%s'}}" % e)   # noqa: E731
F = lambda e: BASE + "forces:\n  - {type: force, body: arm, value: [0, 0, '%s']}\n" % e       # noqa: E731
M = lambda e: base("mass: 1.0", "mass: %s" % e)                                                # noqa: E731
INERTIA = "inertia: {xx: 0.1, yy: 0.1, zz: 0.01}"

# name: (scene text or maker, key path expected (None: no key expected), words of the message; None: must load)
CASES = {
    # anchors, merge keys and aliases in other places
    "merge_bomb_in_body": ("mbsfmu: 1\nname: m\nbodies:\n  arm:\n    <<: " + bomb() + "\n", "bodies.arm", ["aliases"]),
    "alias_bomb_in_parameters": (base("  L: 1.0", "  L: 1.0\n  M: " + bomb()), "parameters.M", ["aliases"]),
    "alias_bomb_in_forces": (BASE + "forces: " + bomb(), "forces", ["aliases"]),
    "merge_key_repeats_a_key": (base("joint: {type: revolute", "joint: {<<: {type: prismatic}, type: revolute"),
                                "bodies.arm.joint.type", ["duplicate key 'type'"]),
    "merge_of_a_scalar": ("mbsfmu: 1\nname: m\nx: &s 3\nbodies:\n  arm: {<<: *s}\n", "bodies.arm", ["merging"]),
    "alias_as_key_repeats": (base("  L: 1.0", "  &k L: 1.0\n  *k : 2.0"), "parameters.L", ["duplicate key"]),
    "list_as_key": (base("  L: 1.0", "  L: 1.0\n  ? [a, b]\n  : 2"), "parameters", ["plain name"]),
    "null_as_key": (base("  L: 1.0", "  L: 1.0\n  ~: 2"), "parameters", ["plain name"]),
    "float_as_parameter_name": (base("  L: 1.0", "  1.5: 2"), "parameters.1.5", ["parameter name"]),
    # long strings, huge lists, deep flow nesting
    "long_model_name": (base("name: demo", "name: " + "a" * 60_000), "name", ["60,000 characters", "at most 200"]),
    "long_coordinate_name": (base("coordinates: [phi]", "coordinates: [" + "c" * 60_000 + "]"),
                             "bodies.arm.joint.coordinates[0]", ["60,000 characters"]),
    "long_quoted_body_name": (base("  arm:\n", '  ? "' + "a" * 5000 + '"\n  :\n'), None, ["not valid as a body name"]),
    "long_method": (BASE + "integrator: {method: " + "x" * 60_000 + "}\n", "integrator.method", ["unknown method"]),
    "parameter_description_list": (base("  L: 1.0", "  L: {value: 1.0, description: [1, 2]}"),
                                   "parameters.L.description", ["expected text"]),
    "200000_parameters": (_many("parameters", 200_000, "  bad: .nan\n"), "parameters", ["10,000 entries"]),
    "100000_forces": (_many("forces", 100_000, ""), "forces", ["10,000 entries"]),
    "100000_outputs": (_many("outputs", 100_000, ""), "outputs", ["10,000 entries"]),
    "star_10000_then_bad": (_star(10_000, "  bad:\n    parent: b5\n    joint: {type: revolute, axis: [0, 0, 0]}\n"),
                            "bodies", ["10,000 entries"]),
    "flat_list_of_300000": (base("parameters:", "description: [" + "1," * 300_000 + "1]\nparameters:"), "description",
                            ["10,000 entries"]),
    "many_small_lists": (base("parameters:", "description: [" + ("[" + "1," * 50 + "1],") * 9_000 + "1]\nparameters:"),
                         "description", ["values in one scene"]),
    "flow_nesting_in_vector": (base("[0, 0, -L/2]", "[0, 0, " + "[" * 70 + "1" + "]" * 70 + "]"),
                               "bodies.arm.center_of_mass[2]", ["nested more than 64"]),
    "mapping_nesting_in_joint": (base("joint: {type: revolute", "joint: {type: " + "{a: " * 70 + "1" + "}" * 70),
                                 "bodies.arm.joint.type", ["nested more than 64"]),
    # tags
    "python_object_parameter": (base("  L: 1.0", "  L: !!python/object:os.system {}"), "parameters.L", ["constructor"]),
    "python_name_mass": (M("!!python/name:os.system"), "bodies.arm.mass", ["constructor"]),
    "python_apply_as_key": (base("  L: 1.0", "  ? !!python/object/apply:os.system [echo PWNED]\n  : 1"), "parameters",
                            ["constructor"]),
    "python_via_tag_directive": ("%TAG !p! tag:yaml.org,2002:python/\n---\n" + M("!p!object/apply:os.system [echo PWNED]"),
                                 "bodies.arm.mass", ["constructor"]),
    "verbatim_python_tag": (M("!<tag:yaml.org,2002:python/object:os.system> {}"), "bodies.arm.mass", ["constructor"]),
    "binary_mass": (M("!!binary AAAA"), "bodies.arm.mass", ["binary"]),
    "set_as_bodies": ("mbsfmu: 1\nname: s\nbodies: !!set {a, b}\n", "bodies", ["set"]),
    "timestamp_tag_mass": (M("!!timestamp 2001-12-14"), "bodies.arm.mass", ["date"]),
    "date_as_mass": (M("2001-12-14"), "bodies.arm.mass", ["date"]),
    "date_as_axis": (base("axis: [0, 1, 0]", "axis: [0, 2024-01-01, 0]"), "bodies.arm.joint.axis[1]", ["date"]),
    "float_tag_nan": (M("!!float 'nan'"), "bodies.arm.mass", ["not finite"]),
    "float_tag_text": (M("!!float 'abc'"), "bodies.arm.mass", ["cannot be read as float"]),
    "int_tag_text": (M("!!int 'abc'"), "bodies.arm.mass", ["cannot be read as int"]),
    "map_tag_on_list": (base("axis: [0, 1, 0]", "axis: !!map [0, 1, 0]"), "bodies.arm.joint.axis", ["cannot be read as map"]),
    "seq_tag_on_scalar": (M("!!seq 1"), "bodies.arm.mass", ["cannot be read as seq"]),
    "str_tag_on_mapping": (base("joint: {type", "joint: !!str {type"), "bodies.arm.joint", ["scalar"]),
    "custom_tag": (M("!foo 1"), "bodies.arm.mass", ["constructor"]),
    "base60_int": (M("190:20:30"), "bodies.arm.mass", ["base-60"]),
    "base60_float": (M("1:30.5"), "bodies.arm.mass", ["base-60"]),
    "octal_int": (M("010"), "bodies.arm.mass", ["octal"]),
    "yaml_version_directive": ("%YAML 9.9\n---\n" + BASE, None, ["invalid YAML"]),
    "two_documents": (BASE + "---\n" + BASE, None, ["single document"]),
    # .inf and .nan in numeric fields (every kind of field)
    **{f"nonfinite_{k}": (v, key, ["not finite"]) for k, (v, key) in {
        "mass": (M(".nan"), "bodies.arm.mass"),
        "inertia_product": (base("zz: 0.01}", "zz: 0.01, xy: .nan}"), "bodies.arm.inertia.xy"),
        "axis": (base("axis: [0, 1, 0]", "axis: [0, .inf, 0]"), "bodies.arm.joint.axis[1]"),
        "joint_at": (base("coordinates: [phi]}", "coordinates: [phi], at: [.inf, 0, 0]}"), "bodies.arm.joint.at[0]"),
        "gravity": (BASE + "gravity: [0, 0, .nan]\n", "gravity[2]"),
        "initial": (base("coordinates: [phi]}", "coordinates: [phi], initial: {phi: .nan}}"), "bodies.arm.joint.initial.phi"),
        "initial_velocity": (base("coordinates: [phi]}", "coordinates: [phi], initial_velocity: {phi: -.inf}}"),
                             "bodies.arm.joint.initial_velocity.phi"),
        "rotation_angle": (base("coordinates: [phi]}", "coordinates: [phi], rotation: {axis: [1, 0, 0], angle: .nan}}"),
                           "bodies.arm.joint.rotation.angle"),
        "rotation_matrix": (base("coordinates: [phi]}", "coordinates: [phi], rotation: {matrix: [[1,0,0],[0,1,0],[0,0,.nan]]}}"),
                            "bodies.arm.joint.rotation.matrix[2][2]"),
        "spring_stiffness": (BASE + "forces:\n  - {type: spring_damper, bodies: [world, arm], stiffness: .nan}\n",
                             "forces[0].stiffness"),
        "spring_length": (BASE + "forces:\n  - {type: spring_damper, bodies: [world, arm], stiffness: 1, length: .inf}\n",
                          "forces[0].length"),
        "joint_spring_offset": (BASE + "forces:\n  - {type: joint_spring_damper, coordinate: phi, stiffness: 1, offset: .nan}\n",
                                "forces[0].offset"),
        "force_value": (F(".nan").replace("'.nan'", ".nan"), "forces[0].value[2]"),
        "output_point": (BASE + "outputs:\n  - {body: arm, point: [0, .nan, 0]}\n", "outputs[0].point[1]"),
        "start": (BASE + "experiment: {start: .nan}\n", "experiment.start"),
        "stop": (BASE + "experiment: {stop: .inf}\n", "experiment.stop"),
        "step": (BASE + "experiment: {step: .nan}\n", "experiment.step"),
        "rtol": (BASE + "integrator: {rtol: .nan}\n", "integrator.rtol"),
        "max_step": (BASE + "integrator: {max_step: .nan}\n", "integrator.max_step"),
        "fixed_step": (BASE + "integrator: {method: rk4, step: .nan}\n", "integrator.step"),
        "rho_inf": (BASE + "integrator: {method: gen_alpha, rho_inf: .nan}\n", "integrator.rho_inf"),
        "beam_length": (elastic("length: 1.0", "length: .inf"), "bodies.beam.elastic.beam.length"),
        "beam_EA": (elastic("rhoA: 0.8", "rhoA: 0.8, EA: .inf"), "bodies.beam.elastic.beam.EA"),
        "damping_ratio": (elastic("modes: 2}", "modes: 2}\n      damping_ratio: .nan"), "bodies.beam.elastic.damping_ratio"),
        "elastic_initial": (elastic("modes: 2}", "modes: 2}\n      initial: {beam.q1: .inf}"),
                            "bodies.beam.elastic.initial.beam.q1"),
        "overflowing_expression": (base("[0, 0, -L/2]", "[0, 0, '1e308*10']"), "bodies.arm.center_of_mass[2]"),
    }.items()},
    "nonfinite_nodal_inline": (BASE + NODAL_BODY % inline(nodal_arrays()).replace("[1.0, 1.0, 1.0]", "[1.0, .nan, 1.0]"),
                               "bodies.plate.elastic.nodal.mass", ["non-finite"]),
    # masses and inertias
    "mass_negative_expression": (M("1-L*2"), "bodies.arm.mass", ["must not be negative"]),
    "massless_moving_body": (M("0").replace(INERTIA, "inertia: {xx: 0, yy: 0, zz: 0}"), "bodies.arm.mass",
                             ["no mass or inertia", "singular"]),
    "massless_chain_end": (BASE + "  tip:\n    parent: arm\n    joint: {type: prismatic, axis: [1, 0, 0]}\n",
                           "bodies.tip.mass", ["'tip'", "no mass or inertia"]),
    "mass_huge": (M("1e300"), "bodies.arm.mass", ["magnitudes"]),
    "mass_subnormal": (M("1e-320"), "bodies.arm.mass", ["magnitudes"]),
    "inertia_huge_spread": (base(INERTIA, "inertia: {xx: 1e300, yy: 1e300, zz: 1}"), "bodies.arm.inertia.xx", ["magnitudes"]),
    "inertia_products_not_psd": (base(INERTIA, "inertia: {xx: 0.1, yy: 0.1, zz: 0.1, xy: 0.5}"), "bodies.arm.inertia",
                                 ["positive semi-definite"]),
    "inertia_matrix_not_symmetric": (base(INERTIA, "inertia: [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]"), "bodies.arm.inertia",
                                     ["symmetric"]),
    "inertia_triangle": (base(INERTIA, "inertia: {xx: 0.01, yy: 0.01, zz: 1}"), "bodies.arm.inertia", ["triangle"]),
    # bytes and characters
    "bom_twice": (_bytes(b"\xef\xbb\xbf\xef\xbb\xbf" + BASE.encode()), None, ["invalid YAML"]),
    "crlf_with_error": (_bytes(M("-1").replace("\n", "\r\n").encode()), "bodies.arm.mass", ["must not be negative"]),
    "nul_in_a_value": (_bytes(M("1\0.0").encode()), None, ["U+0000"]),
    "nul_padding": (_bytes(BASE.encode() + bytes(100)), None, ["U+0000"]),
    "tab_indentation": (base("    parent: world", "\tparent: world"), "bodies.arm", ["invalid YAML", "tabs"]),
    "utf16_with_bom": (_bytes(BASE.encode("utf-16")), None, ["not UTF-8"]),
    "utf16_without_bom": (_bytes(BASE.encode("utf-16-le")), None, ["U+0000"]),
    "utf32": (_bytes(BASE.encode("utf-32")), None, ["not UTF-8"]),
    "overlong_utf8": (_bytes(BASE.encode().replace(b"demo", b"de\xc0\xafmo")), None, ["0xc0"]),
    "utf8_surrogate": (_bytes(BASE.encode().replace(b"demo", b"de\xed\xa0\x80mo")), None, ["0xed"]),
    "noncharacter": (base("name: demo", "description: a\ufffeb\nname: demo"), None, ["U+FFFE"]),
    "line_separator_in_name": (base("name: demo", "name: de\u2028mo"), None, ["invalid YAML"]),
    "whitespace_only": ("   \n\t\n", None, ["invalid YAML"]),
    "comment_only": ("# nothing\n", None, ["YAML mapping"]),
    "scalar_document": ("42\n", None, ["YAML mapping"]),
    # files that are not scene or data files
    "symlink_loop_scene": (_symlink_loop, None, ["cannot read", "symbolic links"]),
    "missing_scene": (lambda d: d / "nope.yaml", None, ["cannot read"]),
    "dev_null": (lambda d: "/dev/null", None, ["not a regular file"]),
    "proc_self_mem": (lambda d: "/proc/self/mem", None, ["cannot read"]),
    "npz_symlink_loop": (_npz_symlink_loop, "bodies.plate.elastic.nodal.file", ["cannot resolve"]),
    "npz_is_a_folder": (lambda d: (d.mkdir(parents=True), (d / "z.npz").mkdir(), _scene(d, BASE + NODAL_BODY % "{file: z.npz}"))[2],
                        "bodies.plate.elastic.nodal.file", ["not a regular file"]),
    "npz_is_the_scene": (BASE + NODAL_BODY % "{file: scene.yaml}", "bodies.plate.elastic.nodal.file", ["not an .npz"]),
    "npz_name_null": (BASE + NODAL_BODY % "{file: null}", "bodies.plate.elastic.nodal.file", ["file name"]),
    "npz_name_too_long": (BASE + NODAL_BODY % ("{file: " + "a" * 5000 + "}"), "bodies.plate.elastic.nodal.file", ["cannot"]),
    "npz_proc_environ": (BASE + NODAL_BODY % "{file: /proc/self/environ}", "bodies.plate.elastic.nodal.file", ["outside"]),
    "npz_dotdot_back_inside": (lambda d: (d.mkdir(parents=True), (d / "sub").mkdir(), np.savez(d / "data.npz", **nodal_arrays()),
                                          _scene(d, BASE + NODAL_BODY % "{file: sub/../data.npz}"))[3], None, None),
    # .npz contents
    "npz_complex": (_npz(_nodal(Phi=nodal_arrays()["Phi"].astype(complex))), "bodies.plate.elastic.nodal.file", ["complex128"]),
    "npz_bool": (_npz(_nodal(mass=np.ones(3, bool))), "bodies.plate.elastic.nodal.file", ["bool"]),
    "npz_unicode": (_npz(_nodal(mass=np.array(["a", "b", "c"]))), "bodies.plate.elastic.nodal.file", ["<U1"]),
    "npz_structured": (_npz(_nodal(mass=np.zeros(3, dtype=[("a", "f8")]))), "bodies.plate.elastic.nodal.file", ["plain numbers"]),
    "npz_datetime": (_npz(_nodal(mass=np.zeros(3, dtype="M8[s]"))), "bodies.plate.elastic.nodal.file", ["datetime64"]),
    "npz_object_header": (_npz(_nodal(mass=_header((3,), "|O", bytes(24)))), "bodies.plate.elastic.nodal.file", ["object"]),
    "npz_code_in_header": (_npz(_nodal(mass=b"\x93NUMPY\x01\x00\x10\x00{'descr': __import__('os').system('echo PWNED')}")),
                           "bodies.plate.elastic.nodal.file", ["cannot read the data file"]),
    "npz_header_length_huge": (_npz(_nodal(mass=b"\x93NUMPY\x02\x00\xff\xff\xff\x7f" + b" " * 100)),
                               "bodies.plate.elastic.nodal.file", ["cannot read the data file"]),
    "npz_shape_2e124": (_npz(_nodal(mass=_header((2**62, 2**62)))), "bodies.plate.elastic.nodal.file", ["claims"]),
    "npz_negative_shape": (_npz(_nodal(mass=_header((-1,), tail=bytes(24)))), "bodies.plate.elastic.nodal.file", ["shape (-1,)"]),
    "npz_not_npy_member": (_npz(_nodal(mass=b"hello")), "bodies.plate.elastic.nodal.file", ["cannot read the data file"]),
    "npz_two_members_one_name": (_npz(list(_nodal().items()) + [("mass.npy", _npy(np.ones(3) * 2))]),
                                 "bodies.plate.elastic.nodal.file", ["two members"]),
    "npz_scalar_array": (_npz(_nodal(mass=np.float64(1.0))), "bodies.plate.elastic.nodal.mass", ["shape ()"]),
    "npz_empty_arrays": (_npz(_nodal(R_RP=np.zeros((0, 3)), mass=np.zeros(0), Phi=np.zeros((0, 3, 2)))),
                         "bodies.plate.elastic.nodal.R_RP", ["N ≥ 1"]),
    "npz_nan_stiffness": (_npz(_nodal(stiffness=np.full((2, 2), np.nan))), "bodies.plate.elastic.nodal.stiffness", ["non-finite"]),
    "npz_four_dimensional_phi": (_npz(_nodal(Phi=np.zeros((3, 3, 2, 1)))), "bodies.plate.elastic.nodal.Phi", ["shape (3, 3, 2, 1)"]),
    "npz_100000_modes": (_npz(_nodal(Phi=np.zeros((3, 3, 100_000)), stiffness=np.eye(1))), "bodies.plate.elastic.nodal.stiffness",
                         ["shape (1, 1)"]),
    "npz_member_outside": (_npz({k: v for k, v in _nodal().items() if k != "mass.npy"} | {"../mass.npy": _npy(np.ones(3))}),
                           "bodies.plate.elastic.nodal", ["missing `mass`"]),
    "npz_big_endian_and_fortran": (_npz(_nodal(mass=np.ones(3, ">f8"), Phi=np.asfortranarray(nodal_arrays()["Phi"]))), None, None),
    # expressions
    "expression_parentheses_2000": (M("'" + "(" * 2000 + "1" + ")" * 2000 + "'"), "bodies.arm.mass", ["nested too deeply"]),
    "expression_minus_4000": (M("'" + "-" * 4000 + "1'"), "bodies.arm.mass", ["nested too deeply"]),
    "expression_power_tower": (M("'2" + "^2" * 2000 + "'"), "bodies.arm.mass", ["nested too deeply"]),
    "expression_drive_calls": (D("sin(" * 800 + "t" + ")" * 800), "bodies.arm.joint.drive.phi", ["nested too deeply"]),
    "expression_10_pow_400": (M("'10^400'"), "bodies.arm.mass", ["cannot evaluate"]),
    "expression_tower_overflow": (M("'2^(2^(2^(2^(2^2))))'"), "bodies.arm.mass", ["cannot evaluate"]),
    "expression_literal_1e999": (M("'1e999'"), "bodies.arm.mass", ["not finite"]),
    "expression_unknown_function": (M("'foo(1)'"), "bodies.arm.mass", ["unknown function 'foo'"]),
    "expression_attribute": (M("'sin.__class__'"), "bodies.arm.mass", ["unknown name"]),
    "expression_dotted_parameter": (M("'L.real'"), "bodies.arm.mass", ["unknown name 'L.real'"]),
    "expression_unicode_digit": (M("'\u0661'"), "bodies.arm.mass", ["ASCII"]),
    "parameter_shadows_function": (base("  L: 1.0", "  L: 1.0\n  sin: 2"), "parameters.sin", ["reserved"]),
    "parameter_shadows_t": (base("  L: 1.0", "  L: 1.0\n  t: 3"), "parameters.t", ["reserved"]),
    "parameter_is_t": (base("  L: 1.0", "  L: t"), "parameters.L", ["finite number"]),
    "t_in_mass": (M("'t+1'"), "bodies.arm.mass", ["unknown name 't'"]),
    "complex_power": (M("'(-8)^(1/3)'"), "bodies.arm.mass", ["cannot evaluate"]),
    "zero_to_negative_power": (M("'0^-1'"), "bodies.arm.mass", ["cannot evaluate"]),
    "asin_domain": (M("'asin(2)'"), "bodies.arm.mass", ["math domain"]),
    "division_by_parameter_expression": (M("'1/(L-1)'"), "bodies.arm.mass", ["division by zero"]),
    "drive_pole_between_samples": (D("1/(t-0.3333)"), "bodies.arm.joint.drive.phi", ["divides by zero near t = 0.3333"]),
    "force_pole_between_samples": (F("1/(t-1/3)"), "forces[0].value[2]", ["divides by zero near t = 0.333333"]),
    "force_tan_pole": (F("tan(t)"), "forces[0].value[2]", ["divides by zero near t = 1.5708"]),
    "force_double_pole": (F("1/(t-0.3333)^2"), "forces[0].value[2]", ["divides by zero near t = 0.3333"]),
    "force_log_touches_zero": (F("log(abs(t-0.3333))"), "forces[0].value[2]", ["near t = 0.3333"]),
    "force_sqrt_dips_below_zero": (F("sqrt(cos(t)+0.99999)"), "forces[0].value[2]", ["domain near t = 3.14159"]),
    "force_acos_dips": (F("acos(1.000001*cos(t+0.1))"), "forces[0].value[2]", ["domain near t = 3.04159"]),
    "force_fractional_power_dips": (F("(cos(t)+0.99999)^1.5"), "forces[0].value[2]", ["domain near t = 3.14159"]),
    "drive_kink_velocity_jump": (D("abs(t-0.3333)"), "bodies.arm.joint.drive.phi", ["first time derivative", "near t = 0.3333"]),
    "force_overflow_late": (F("exp(100*t)"), "forces[0].value[2]", ["t = 7.1"]),
    "drive_velocity_overflow": (D("exp(t^3)"), "bodies.arm.joint.drive.phi", ["first time derivative"]),
    "force_pole_inside_min": (F("1/min(t-0.3333, 1)"), "forces[0].value[2]", ["divides by zero near t = 0.3333"]),
    "force_defined_everywhere": (F("1/(1+t^2) + sqrt(2+cos(t)) + log(1.5+sin(t)) + tan(t/8)"), None, None),
    "drive_smooth": (D("0.5*sin(2*pi*t) + 1/(t+0.001)"), None, None),
    # integrator and experiment settings
    "step_zero": (BASE + "experiment: {step: 0}\n", "experiment.step", ["must be positive"]),
    "step_negative": (BASE + "experiment: {step: -0.1}\n", "experiment.step", ["must be positive"]),
    "step_expression_zero": (BASE + "experiment: {step: 'L-1'}\n", "experiment.step", ["must be positive"]),
    "stop_before_start": (BASE + "experiment: {start: 2, stop: 1}\n", "experiment.stop", ["must come after start"]),
    "stop_equals_start": (BASE + "experiment: {start: 1, stop: 1}\n", "experiment.stop", ["must come after start"]),
    "span_of_2e308": (BASE + "experiment: {start: -1e308, stop: 1e308}\n", "experiment.start", ["magnitudes"]),
    "too_many_points": (BASE + "experiment: {start: -1e50, stop: 1e50}\n", "experiment.stop", ["communication points"]),
    "rtol_zero": (BASE + "integrator: {rtol: 0}\n", "integrator.rtol", ["must be positive"]),
    "atol_zero": (BASE + "integrator: {atol: 0}\n", "integrator.atol", ["must be positive"]),
    "max_steps_misspelt": (BASE + "integrator: {max_steps: 10}\n", "integrator.max_steps", ["did you mean 'max_step'"]),
    "fixed_step_negative": (BASE + "integrator: {method: rk4, step: -0.01}\n", "integrator.step", ["must not be negative"]),
    "max_step_1e-300": (BASE + "integrator: {max_step: 1e-300}\n", "integrator.max_step", ["steps"]),
    "rho_inf_2": (BASE + "integrator: {method: gen_alpha, rho_inf: 2}\n", "integrator.rho_inf", ["[0, 1]"]),
    "method_list": (BASE + "integrator: {method: [rk4]}\n", "integrator.method", ["unknown method"]),
    "integrator_scalar": (BASE + "integrator: rk4\n", "integrator", ["expected a mapping"]),
    "rtol_boolean": (BASE + "integrator: {rtol: true}\n", "integrator.rtol", ["boolean"]),
    # duplicates
    "duplicate_top_key": (BASE + "name: other\n", "name", ["duplicate key 'name'"]),
    "duplicate_body": (BASE + "  arm:\n    parent: world\n    joint: {type: fixed}\n", "bodies.arm", ["duplicate key 'arm'"]),
    "duplicate_flow_key": (base("joint: {type: revolute", "joint: {type: revolute, type: fixed"), "bodies.arm.joint.type",
                           ["duplicate key"]),
    "duplicate_int_and_string_key": (base("  L: 1.0", "  L: 1.0\n  '1': 2\n  1: 3"), "parameters.1", ["duplicate key '1'"]),
    # the neighbours that must still load
    "bom_once": (_bytes(b"\xef\xbb\xbf" + BASE.encode()), None, None),
    "crlf": (_bytes(BASE.replace("\n", "\r\n").encode()), None, None),
    "tabs_inside_flow": (base("[0, 1, 0]", "[0,\t1,\t0]"), None, None),
    "quoted_octal_text": (base("parameters:", "description: '010'\nparameters:"), None, None),
}
FILE_LEVEL = ("symlink_loop_scene", "missing_scene", "dev_null", "proc_self_mem")  # no line: the file cannot be read


def _case_path(name, root):
    make = CASES[name][0]
    d = root / name
    if callable(make):
        return make(d)
    d.mkdir(parents=True)
    (d / "scene.yaml").write_text(make, encoding="utf-8")
    return d / "scene.yaml"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile_extra")
    paths = {name: _case_path(name, root) for name in CASES}
    out = run_bounded([(n, p, False) for n, p in paths.items()], root)
    out["_paths"] = {n: str(p) for n, p in paths.items()}
    out["_root"] = str(root)
    return out


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n][2] is not None])
def test_new_hostile_scene_is_refused_with_file_line_key_and_hint(name, results):
    _, key, words = CASES[name]
    r, path = results[name], results["_paths"][name]
    assert r["type"] == "ModelError", r
    assert r["cpu"] < CPU_LARGE.get(name, CPU_SECONDS), r["cpu"]
    assert r["length"] < 1000 and r["hint"], r
    assert r["file"] == path, r
    if name not in FILE_LEVEL:
        assert isinstance(r["line"], int) and r["text"].startswith(f"{path}:{r['line']}: "), r
    if key is not None:   # the key, or one below it (an alias bomb names the list item where it went off)
        assert r["key"] == key or r["key"].startswith((key + ".", key + "[")), r
    for w in words:
        assert w in r["text"], (w, r["text"])


@pytest.mark.parametrize("name", [n for n in CASES if CASES[n][2] is None])
def test_valid_neighbours_still_load(name, results):
    assert results[name]["type"] is None, results[name]


def test_nothing_executed_and_memory_bounded(results):
    assert results["maxrss_mb"] < 800, results["maxrss_mb"]
    assert not any("PWNED" in files for _, _, files in os.walk(results["_root"]))


def test_cli_prints_one_line_without_traceback(results):
    """`mbsfmu check` on hostile files: one line on stderr, exit status 1, no traceback."""
    names = ["alias_bomb_in_forces", "npz_code_in_header", "npz_symlink_loop", "float_tag_text", "symlink_loop_scene",
             "200000_parameters", "force_tan_pole", "utf16_with_bom", "massless_moving_body"]
    code = ("import sys\nfrom mbsfmu.cli import main\n"
            "for p in sys.argv[1:]:\n    print('STATUS', main(['check', p]), flush=True)\n")
    r = subprocess.run([sys.executable, "-c", code] + [results["_paths"][n] for n in names],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["STATUS", "1"] * len(names), r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == len(names) and "Traceback" not in r.stderr, r.stderr
    for n, line in zip(names, lines):
        assert results["_paths"][n] in line, (n, line)
