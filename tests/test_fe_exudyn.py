"""Flexible pendulum from a solid FE body: mbsfmu against Exudyn's ObjectFFRFreducedOrder (issue 24).

A slender aluminium strip 1 m × 40 mm × 20 mm, tet10 (scikit-fem via `elastic: fe: {mesh, material}`), its end
face x = 0 tied rigidly (RBE2) to the reference point at the hinge, Craig–Bampton with 6 fixed-interface modes,
hinged about world y and swinging from horizontal under gravity.  Exudyn gets the same full consistent M, K
(fe_mesh.assemble_solid on the same file) and nodes in its FEMinterface, computes its OWN Craig–Bampton modes
(ComputeHurtyCraigBamptonModes, RBE2 interface = the clamped face) and its own FFRF invariants from the full M;
gravity is the consistent nodal load M·g (see test_exudyn_flexible.exudyn_gravity for why not `gravity=`).
Only the integrators differ: ours is converged (dop853, rtol 1e-10), Exudyn's generalized-α (ρ∞ = 1,
trapezoidal) has an O(h²) error, so the tip difference must fall about 4× per halved step.
"""

import numpy as np
import pytest

exu = pytest.importorskip("exudyn")
skfem = pytest.importorskip("skfem")
meshio = pytest.importorskip("meshio")

import mbsfmu  # noqa: E402
from mbsfmu.bodies.fe_mesh import assemble_solid  # noqa: E402
from mbsfmu.bodies.tree import node_point  # noqa: E402

L, B, H = 1.0, 0.04, 0.02
E, NU, RHO = 7.0e10, 0.33, 2700.0
MODES, T_END = 6, 0.2


pytestmark = pytest.mark.usefixtures("private_fe_cache")  # conftest.py: each test's own FE cache


def strip_mesh(folder):
    """tet4 corners of the strip [0, L] × [−B/2, B/2] × [−H/2, H/2] (positive volumes) written as VTU."""
    m = skfem.MeshTet.init_tensor(np.linspace(0, L, 17), np.linspace(-B / 2, B / 2, 3), np.linspace(-H / 2, H / 2, 2))
    p, t = m.p.T.copy(), m.t.T.copy()
    d = p[t[:, 1:]] - p[t[:, :1]]
    flip = np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) < 0
    t[flip] = t[flip][:, [1, 0, 2, 3]]
    meshio.write(folder / "strip.vtu", meshio.Mesh(p, [("tetra", t)]))
    return folder / "strip.vtu"


def mbsfmu_tip(folder, root, tip, rtol=1e-10):
    """Times, hinge angle and tip node path of the scene at the 10 ms points (dop853 at rtol 1e-10: within 1e-14 m
    of rtol 1e-13, far below Exudyn's step error)."""
    (folder / "s.yaml").write_text(f"""mbsfmu: 1
name: fe_pendulum
gravity: [0, 0, -9.81]
bodies:
  strip:
    parent: world
    joint: {{type: revolute, axis: [0, 1, 0], coordinates: [theta]}}
    elastic:
      fe:
        mesh: strip.vtu
        element: tet10
        material: {{E: {E}, nu: {NU}, rho: {RHO}}}
        interface: {{nodes: {root.tolist()}, reference: [0, 0, 0]}}
        method: craig-bampton
        modes: {MODES}
        keep: [{tip}]
""")
    spec = mbsfmu.load(folder / "s.yaml")
    ev = mbsfmu.compile(spec)
    t, Y, YD = mbsfmu.simulate(spec, stop=T_END, step=0.01, method="dop853", rtol=rtol, atol=rtol * 1e-2)
    body = ev.model.index["strip"]
    tip_path = [node_point(ev.model, ev.kinematics(y, yd, tt), body, -1)[0] for y, yd, tt in zip(Y, YD, t)]
    return t, Y[:, 0], np.array(tip_path)


def exudyn_tip(fe, root, tip, ts, h):
    """Exudyn from the full M, K with its own Craig–Bampton modes; tip node path at ts with generalized-α step h."""
    import exudyn.itemInterface as eii
    from exudyn.FEM import FEMinterface, HCBstaticModeSelection, ObjectFFRFreducedOrderInterface
    fem = FEMinterface()
    fem.nodes, fem.massMatrix, fem.stiffnessMatrix = {"Position": fe.nodes}, fe.M, fe.K
    fem.ComputeHurtyCraigBamptonModes(boundaryNodesList=[root], nEigenModes=MODES,
                                      computationMode=HCBstaticModeSelection.RBE2)
    cms = ObjectFFRFreducedOrderInterface(fem)
    mbs = exu.SystemContainer().AddSystem()
    obj = cms.AddObjectFFRFreducedOrder(mbs)
    body = obj["oFFRFreducedOrder"]
    # consistent nodal gravity M·g = m_k g with m_k the row sums of the scalar mass (M = M_s ⊗ E; negative at
    # tet10 corners): one force m g on the mass-weighted mean of all nodes
    m_k = np.asarray(fe.M[0::3, 0::3].sum(axis=1)).ravel()
    mg = mbs.AddMarker(eii.MarkerSuperElementPosition(bodyNumber=body, meshNodeNumbers=list(range(fe.n_nodes)),
                                                      weightingFactors=(m_k / m_k.sum()).tolist()))
    mbs.AddLoad(eii.LoadForceVector(markerNumber=mg, loadVector=[0.0, 0.0, -9.81 * m_k.sum()]))
    ground = mbs.AddObject(eii.ObjectGround())
    mG = mbs.AddMarker(eii.MarkerBodyRigid(bodyNumber=ground, localPosition=[0, 0, 0]))
    mR = mbs.AddMarker(eii.MarkerNodeRigid(nodeNumber=obj["nRigidBody"]))
    mbs.AddObject(eii.GenericJoint(markerNumbers=[mG, mR], constrainedAxes=[1, 1, 1, 1, 0, 1]))   # revolute about y
    mTip = mbs.AddMarker(eii.MarkerSuperElementPosition(bodyNumber=body, meshNodeNumbers=[tip], weightingFactors=[1.0]))
    sTip = mbs.AddSensor(eii.SensorMarker(markerNumber=mTip, outputVariableType=exu.OutputVariableType.Position,
                                          storeInternal=True))
    mbs.Assemble()
    s = exu.SimulationSettings()
    s.timeIntegration.endTime = T_END
    s.timeIntegration.numberOfSteps = int(round(T_END / h))
    s.timeIntegration.generalizedAlpha.spectralRadius = 1.0   # trapezoidal: no numerical damping, O(h²)
    s.timeIntegration.verboseMode = 0
    s.solution.file.write = False
    s.solution.sensors.writePeriod = 0.01
    exu.SolveDynamic(mbs, s)
    D = np.asarray(mbs.GetSensorStoredData(sTip))
    return np.column_stack([np.interp(ts, D[:, 0], D[:, k]) for k in (1, 2, 3)])


def rigid_path(X, theta):
    """X turned about y by theta (the undeformed strip's path)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.column_stack([c * X[0] + s * X[2], X[1] + 0 * theta, -s * X[0] + c * X[2]])


def test_fe_pendulum_tip_matches_exudyn_up_to_its_step_error(tmp_path):
    """The tip difference falls as Exudyn's O(h²) step error: ≥ 2.8× per halved step (measured 4.0× and 3.2×,
    not yet the asymptotic 4×: the sixth mode, 572 Hz, has ωh = 0.7 at h = 2e-4), to 0.3 % of the elastic
    deflection."""
    path = strip_mesh(tmp_path)
    fe = assemble_solid(path.name, E, NU, RHO, element="tet10", base=tmp_path)
    root = np.flatnonzero(np.abs(fe.nodes[:, 0]) < 1e-12)
    tip = int(np.flatnonzero((np.abs(fe.nodes[:, 0] - L) < 1e-12) & (np.abs(fe.nodes[:, 2] - H / 2) < 1e-12))[0])
    t, theta, ours = mbsfmu_tip(tmp_path, root, tip)
    elastic = np.linalg.norm(ours - rigid_path(fe.nodes[tip], theta), axis=1).max()
    diffs = [np.linalg.norm(ours - exudyn_tip(fe, root, tip, t, h), axis=1).max() for h in (2e-4, 1e-4, 5e-5)]
    print("max |Δ r_tip| at h = 2e-4, 1e-4, 5e-5:", diffs, "elastic deflection", elastic)
    assert np.ptp(ours[:, 2]) > 0.15 and elastic > 1e-4      # it swings down and bends
    for coarse, fine in zip(diffs, diffs[1:]):
        assert 2.8 < coarse / fine < 5.0, diffs
    assert diffs[-1] < 3e-3 * elastic, (diffs, elastic)
