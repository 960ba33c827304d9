"""COLLADA (.dae) visual meshes (issue 25): triangles of every instanced geometry in world units (node
transforms, <unit meter>, <up_axis>) against closed forms; a real robot's DAE against its collision STL; hostile
XML (entity bombs, external entities, instancing that multiplies triangles) refused with one ModelError quickly."""
from __future__ import annotations

import sysconfig
import time
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.animation.mesh import read_mesh
from mbsfmu.errors import ModelError
from mbsfmu import limits

ROBOTS = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"

# a unit cube [0, 1]^3: 8 corners, 6 quads as a <polylist> (fanned into 12 triangles)
CUBE_V = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_QUADS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def dae(node_xml, unit=1.0, up="Z_UP", library_nodes="", primitive="polylist"):
    coords = " ".join(f"{c:g}" for v in CUBE_V for c in v)
    if primitive == "polylist":
        prim = (f'<polylist count="6"><input semantic="VERTEX" source="#v" offset="0"/>'
                f'<vcount>{" ".join("4" for _ in CUBE_QUADS)}</vcount>'
                f'<p>{" ".join(str(i) for q in CUBE_QUADS for i in q)}</p></polylist>')
    else:
        tris = [(q[0], q[k], q[k + 1]) for q in CUBE_QUADS for k in (1, 2)]
        prim = (f'<triangles count="12"><input semantic="VERTEX" source="#v" offset="0"/>'
                f'<p>{" ".join(str(i) for t in tris for i in t)}</p></triangles>')
    return f"""<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
<asset><unit meter="{unit}" name="u"/><up_axis>{up}</up_axis></asset>
<library_geometries><geometry id="cube"><mesh>
<source id="p"><float_array id="pa" count="24">{coords}</float_array>
<technique_common><accessor source="#pa" count="8" stride="3"><param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/></accessor></technique_common></source>
<vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
{prim}
</mesh></geometry></library_geometries>
{library_nodes}
<library_visual_scenes><visual_scene id="s">{node_xml}</visual_scene></library_visual_scenes>
<scene><instance_visual_scene url="#s"/></scene>
</COLLADA>"""


CUBE_NODE = '<node id="n"><translate>10 20 30</translate><rotate>0 0 1 90</rotate><scale>2 2 2</scale><instance_geometry url="#cube"/></node>'


def corners(tris):
    return {tuple(np.round(p, 6) + 0.0) for p in tris.reshape(-1, 3)}


def expected(transform):
    return {tuple(np.round(transform(np.array(v, float)), 6) + 0.0) for v in CUBE_V}


def write(tmp_path, text, name="m.dae"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("primitive", ["polylist", "triangles"])
def test_cube_node_transform_and_unit_give_world_corners(tmp_path, primitive):
    """translate · rotate(z, 90°) · scale(2), then millimetres → metres: the 8 corners in closed form, 12
    triangles, each a right isosceles triangle of legs 2 mm (area 2e-6 m²: none degenerate)."""
    tris = read_mesh(write(tmp_path, dae(CUBE_NODE, unit=0.001, primitive=primitive)))
    Rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    assert tris.shape == (12, 3, 3)
    assert corners(tris.astype(float)) == expected(lambda v: 0.001 * (np.array([10, 20, 30]) + Rz @ (2 * v)))
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    assert np.allclose(area, 0.5 * 0.002**2, rtol=1e-5)


def test_y_up_turns_to_z_up(tmp_path):
    """Y_UP: the file's +y is up, so (x, y, z) is drawn at (x, -z, y) (a right-handed turn about x)."""
    node = '<node id="n"><translate>0 5 0</translate><instance_geometry url="#cube"/></node>'
    tris = read_mesh(write(tmp_path, dae(node, up="Y_UP")))
    assert corners(tris.astype(float)) == expected(lambda v: np.array([v[0], -v[2], v[1] + 5]))


def test_nested_instance_nodes_compose(tmp_path):
    """A geometry reached through <instance_node> twice, under two translated parents: two cubes."""
    lib = '<library_nodes><node id="leaf"><translate>1 0 0</translate><instance_geometry url="#cube"/></node></library_nodes>'
    node = ('<node id="a"><translate>0 0 0</translate><instance_node url="#leaf"/></node>'
            '<node id="b"><translate>0 0 7</translate><instance_node url="#leaf"/></node>')
    tris = read_mesh(write(tmp_path, dae(node, library_nodes=lib)))
    assert len(tris) == 24
    assert corners(tris.astype(float)) == expected(lambda v: v + [1, 0, 0]) | expected(lambda v: v + [1, 0, 7])


@pytest.mark.skipif(not ROBOTS.is_dir(), reason="example-robot-data is not installed")
@pytest.mark.parametrize("link", ["base", "shoulder", "upperarm", "forearm", "wrist1", "wrist2", "wrist3"])
def test_ur5_visual_dae_matches_its_collision_stl(link):
    """The UR5's visual DAE (Y_UP or Z_UP, unit as written) against the collision STL of the same link: the
    two are drawn from one CAD model, so their bounding boxes agree to 2 mm (measured: 0.02–0.53 mm)."""
    meshes = ROBOTS / "ur_description/meshes/ur5"
    visual, collision = read_mesh(meshes / f"visual/{link}.dae"), read_mesh(meshes / f"collision/{link}.stl")
    lo_v, hi_v = visual.reshape(-1, 3).min(0), visual.reshape(-1, 3).max(0)
    lo_c, hi_c = collision.reshape(-1, 3).min(0), collision.reshape(-1, 3).max(0)
    assert np.allclose(lo_v, lo_c, atol=0.002) and np.allclose(hi_v, hi_c, atol=0.002), (lo_v, hi_v, lo_c, hi_c)


LAUGHS = ('<?xml version="1.0"?><!DOCTYPE COLLADA [<!ENTITY a "aaaaaaaaaa">'
          + "".join(f'<!ENTITY {chr(98 + i)} "{("&" + chr(97 + i) + ";") * 10}">' for i in range(9))
          + ']><COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1"><asset><contributor><author>&j;</author></contributor></asset></COLLADA>')
EXTERNAL = ('<?xml version="1.0"?><!DOCTYPE COLLADA [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
            '<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1"><asset><contributor><author>&x;</author></contributor></asset></COLLADA>')


def doubling(levels):
    """Node i instances node i-1 twice: 2**levels cubes of 12 triangles from a file of a few kB."""
    lib = '<library_nodes><node id="n0"><instance_geometry url="#cube"/></node>' + "".join(
        f'<node id="n{i}"><instance_node url="#n{i - 1}"/><instance_node url="#n{i - 1}"/></node>' for i in range(1, levels + 1))
    return dae(f'<node id="top"><instance_node url="#n{levels}"/></node>', library_nodes=lib + "</library_nodes>")


@pytest.mark.parametrize("name, text, words", [
    ("laughs", LAUGHS, "refused XML"),
    ("external", EXTERNAL, "refused XML"),
    ("doubling", doubling(20), "more than 4,096 geometry instances"),   # a million cubes asked for
    ("cycle", dae('<node id="top"><instance_node url="#c"/></node>',
                  library_nodes='<library_nodes><node id="c"><instance_node url="#d"/></node><node id="d"><instance_node url="#c"/></node></library_nodes>'), "COLLADA"),
    ("broken", "<COLLADA><asset>", "not XML"),
], ids=lambda v: v if isinstance(v, str) and len(v) < 12 else "")
def test_hostile_dae_is_one_model_error_within_a_second(tmp_path, name, text, words):
    p = write(tmp_path, text)
    t0 = time.process_time()
    with pytest.raises(ModelError) as e:
        read_mesh(p)
    assert time.process_time() - t0 < 1.0
    assert words in str(e.value) and str(p) in str(e.value) and "\n" not in str(e.value)


def test_over_the_triangle_limit_is_refused(tmp_path, monkeypatch):
    """Two instanced cubes are 24 triangles: under a limit of 20 refused before the second is built, at 24 read."""
    lib = '<library_nodes><node id="leaf"><instance_geometry url="#cube"/></node></library_nodes>'
    p = write(tmp_path, dae('<node id="a"><instance_node url="#leaf"/><instance_node url="#leaf"/></node>', library_nodes=lib))
    monkeypatch.setattr(limits, "MESH_TRIANGLES", 24)
    assert len(read_mesh(p)) == 24
    monkeypatch.setattr(limits, "MESH_TRIANGLES", 20)
    with pytest.raises(ModelError, match="more than 20 triangles"):
        read_mesh(p)


def _robot_with_package_meshes(folder, dae_text):
    """folder/robot.urdf: a pendulum link drawn by package://arm/meshes/link.dae, the mesh in folder/pkgs/arm."""
    mesh = folder / "pkgs/arm/meshes/link.dae"
    mesh.parent.mkdir(parents=True)
    mesh.write_text(dae_text)
    (folder / "robot.urdf").write_text(
        '<?xml version="1.0"?>\n<robot name="r"><link name="world"/><joint name="j" type="revolute"><parent link="world"/>'
        '<child link="arm"/><axis xyz="1 0 0"/></joint><link name="arm"><inertial><origin xyz="0 0 -0.5"/><mass value="1"/>'
        '<inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial>'
        '<visual><geometry><mesh filename="package://arm/meshes/link.dae" scale="2 2 2"/></geometry></visual></link></robot>\n')
    return folder / "robot.urdf"


def test_direct_urdf_load_draws_package_meshes_in_the_named_folders(tmp_path):
    """mbsfmu.load(robot.urdf, package_dirs=[...]): the package:// DAE becomes a mesh shape read as the cube it
    is; without the folder it is skipped with the note; a folder outside the URDF's is trusted (issue 34: the user
    named it), one that is not a folder refused."""
    urdf = _robot_with_package_meshes(tmp_path / "robot", dae(CUBE_NODE, unit=0.001))
    scene = mbsfmu.load(urdf, package_dirs=["pkgs"])
    (shape,) = scene.spec["bodies"][0]["shape"]
    assert shape["type"] == "mesh" and shape["file"] == "pkgs/arm/meshes/link.dae" and shape["scale"] == [2, 2, 2]
    assert len(read_mesh(urdf.parent / shape["file"])) == 12
    page = Path(mbsfmu.animate(scene, str(tmp_path / "anim.html"), stop=0.05))
    assert page.stat().st_size > 0
    with pytest.warns(UserWarning, match="1 in no named package folder"):
        assert not mbsfmu.load(urdf).spec["bodies"][0].get("shape")
    (tmp_path / "elsewhere").mkdir()
    with pytest.warns(UserWarning, match="1 in no named package folder"):  # searched, and it holds no package 'arm'
        mbsfmu.load(urdf, package_dirs=["../elsewhere"])
    with pytest.raises(ModelError, match=r"robot\.urdf: package_dirs\[0\]: the package folder '\.\./nowhere' is not a folder"):
        mbsfmu.load(urdf, package_dirs=["../nowhere"])
    with pytest.raises(ModelError, match="expected a list"):
        mbsfmu.load(urdf, package_dirs="pkgs")
    (tmp_path / "scene.yaml").write_text("mbsfmu: 1\n")
    with pytest.raises(ModelError, match="for a URDF loaded directly"):
        mbsfmu.load(tmp_path / "scene.yaml", package_dirs=["pkgs"])


@pytest.mark.skipif(not ROBOTS.is_dir(), reason="example-robot-data is not installed")
def test_cli_package_dir_draws_a_real_dae(tmp_path, capsys):
    """`mbsfmu animate robot.urdf --package-dir pkgs`: the UR5 forearm's real DAE drawn through the command."""
    from mbsfmu import cli
    urdf = _robot_with_package_meshes(tmp_path, (ROBOTS / "ur_description/meshes/ur5/visual/forearm.dae").read_text())
    assert cli.main(["animate", str(urdf), "--package-dir", "pkgs", "--stop", "0.05", "-o", str(tmp_path / "a.html")]) in (0, None)
    assert (tmp_path / "a.html").stat().st_size > 1000
    assert cli.main(["check", str(urdf), "--package-dir", "../x"]) not in (0, None)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a folder" in err[0], err


def test_convert_package_dir_names_the_mesh_and_the_yaml_loads(tmp_path):
    """`mbsfmu convert robot.urdf --package-dir pkgs`: the written scene names the DAE relative to itself and
    loads to the same mesh shape as the URDF loaded with package_dirs."""
    from mbsfmu import cli
    urdf = _robot_with_package_meshes(tmp_path, dae(CUBE_NODE))
    assert cli.main(["convert", str(urdf), "--package-dir", "pkgs", "-o", str(tmp_path / "robot.yaml")]) in (0, None)
    converted, direct = mbsfmu.load(tmp_path / "robot.yaml"), mbsfmu.load(urdf, package_dirs=["pkgs"])
    assert converted.spec["bodies"][0]["shape"] == direct.spec["bodies"][0]["shape"]
    assert direct.spec["bodies"][0]["shape"][0]["file"] == "pkgs/arm/meshes/link.dae"
