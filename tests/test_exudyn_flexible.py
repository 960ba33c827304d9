"""Flexible pendulum: mbsfmu against Exudyn's ObjectFFRFreducedOrder built from the same data.

Both models are the same linear FFRF body (dynamic_stiffening: false): Exudyn receives as its "mesh"
the mbsfmu beam's Gauss mass points plus the tip mass (lumped, 3 dofs per point), the mode basis
Φ at those points, and a full stiffness matrix K_f = M_f Φ M_m⁻¹ K_m M_m⁻¹ Φᵀ M_f chosen so that
Exudyn's reduction Φᵀ K_f Φ gives back mbsfmu's modal K_m (asserted).  The pendulum swings from
horizontal under gravity; the tip trajectories are compared over 1 s.
"""

import numpy as np
import pytest

import mbsfmu
from mbsfmu.simulation import simulate

exu = pytest.importorskip("exudyn")
sp = pytest.importorskip("scipy.sparse")

SCENE = """
mbsfmu: 1
name: flexible_pendulum_exudyn
gravity: [0, 0, -9.81]
bodies:
  beam:
    parent: world
    joint: {type: revolute, axis: [0, 1, 0], coordinates: [theta]}
    elastic:
      beam: {length: 1.0, EI: [43.75, 700.0], rhoA: 0.785, elements: 8, modes: 2, clamped: start}
      dynamic_stiffening: false
  tip:
    parent: beam
    joint: {type: fixed, node: -1}
    mass: M_TIP
"""
M_TIP, T_END = 0.2, 1.0


def exudyn_tip(nodal, T=T_END, h=1e-3):
    import exudyn.itemInterface as eii
    from exudyn.FEM import FEMinterface, ObjectFFRFreducedOrderInterface
    p = nodal.points()
    R = np.vstack([p.R, nodal.R_RP[-1]])
    m = np.concatenate([p.m, [M_TIP]])
    Phi = np.concatenate([p.Phi, nodal.Phi[-1:]], axis=0).reshape(3 * len(m), nodal.n)
    Mf = np.kron(np.diag(m), np.eye(3))
    Mm_inv = np.linalg.inv(Phi.T @ Mf @ Phi)
    Kf = Mf @ Phi @ Mm_inv @ nodal.stiffness @ Mm_inv @ Phi.T @ Mf
    fem = FEMinterface()
    fem.nodes = {"Position": R}
    fem.massMatrix, fem.stiffnessMatrix = sp.csr_matrix(Mf), sp.csr_matrix(Kf)
    fem.modeBasis = {"matrix": Phi, "type": "NormalModes"}
    cms = ObjectFFRFreducedOrderInterface(fem)
    np.testing.assert_allclose(cms.stiffnessMatrixReduced, nodal.stiffness, atol=1e-9 * np.abs(nodal.stiffness).max())

    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    obj = cms.AddObjectFFRFreducedOrder(mbs, gravity=[0, 0, -9.81])
    ground = mbs.AddObject(eii.ObjectGround())
    mG = mbs.AddMarker(eii.MarkerBodyRigid(bodyNumber=ground, localPosition=[0, 0, 0]))
    mR = mbs.AddMarker(eii.MarkerNodeRigid(nodeNumber=obj["nRigidBody"]))
    mbs.AddObject(eii.GenericJoint(markerNumbers=[mG, mR], constrainedAxes=[1, 1, 1, 1, 0, 1]))  # revolute about y
    mTip = mbs.AddMarker(eii.MarkerSuperElementPosition(bodyNumber=obj["oFFRFreducedOrder"],
                                                        meshNodeNumbers=[len(m) - 1], weightingFactors=[1.0]))
    sTip = mbs.AddSensor(eii.SensorMarker(markerNumber=mTip, outputVariableType=exu.OutputVariableType.Position,
                                          storeInternal=True))
    mbs.Assemble()
    s = exu.SimulationSettings()
    s.timeIntegration.numberOfSteps = int(round(T / h))
    s.timeIntegration.endTime = T
    s.timeIntegration.generalizedAlpha.spectralRadius = 1.0   # no numerical damping
    s.timeIntegration.verboseMode = 0
    s.solution.file.write = False
    s.solution.sensors.writePeriod = 0.01
    exu.SolveDynamic(mbs, s)
    return mbs.GetSensorStoredData(sTip)


def test_flexible_pendulum_matches_exudyn(tmp_path):
    scene = mbsfmu.loads(SCENE.replace("M_TIP", repr(M_TIP)))
    ev = mbsfmu.compile(scene)
    nodal = next(b for b in ev.model.bodies if b.elastic).nodal
    t, Y, YD = simulate(scene, stop=T_END, step=0.01, rtol=1e-8, atol=1e-10)
    ours = np.array([ev.output_point(ev.kinematics(y, yd, tt), {"body": "beam", "node": -1, "point": [0, 0, 0]})[0]
                     for y, yd, tt in zip(Y, YD, t)])
    D = exudyn_tip(nodal)
    theirs = np.column_stack([np.interp(t, D[:, 0], D[:, k]) for k in (1, 2, 3)])
    diff = np.linalg.norm(ours - theirs, axis=1)
    # elastic part: tip position minus the rigid chord direction of the reference frame
    rigid = np.column_stack([np.cos(Y[:, 0]), 0 * t, -np.sin(Y[:, 0])])
    elastic = np.linalg.norm(ours - rigid, axis=1)

    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
        for k, c in ((0, "x"), (2, "z")):
            ax[0].plot(t, ours[:, k], label=f"mbsfmu {c}")
            ax[0].plot(t, theirs[:, k], "--", label=f"Exudyn {c}")
        ax[0].legend()
        ax[1].semilogy(t[1:], diff[1:], label="|Δ r_tip|")
        ax[1].semilogy(t[1:], elastic[1:], label="elastic deflection")
        ax[1].legend()
        fig.savefig(tmp_path / "exudyn_flexible_pendulum.png")
        plt.close(fig)
    except ImportError:
        pass

    # Motion: the tip travels ~2 m (horizontal → vertical → horizontal on the other side), the
    # elastic deflection (tip minus rigid chord) peaks at ~5 mm.  Measured max Δ ≈ 0.95 mm, the same
    # with Exudyn's step 1e-3 s or 2e-4 s and our rtol 1e-8 or 1e-9: a model difference of ~20 % of
    # the elastic part that is not integration error and is NOT yet explained (open item).
    # Tolerance: 0.1 % of the tip excursion (rigid motion agrees) and 25 % of the peak elastic
    # deflection (so a missing or doubled elastic term would still fail).
    assert np.ptp(ours[:, 0]) > 1.9
    assert diff.max() < 1e-3 * np.ptp(ours, axis=0).max()
    assert diff.max() < 0.25 * elastic.max(), (diff.max(), elastic.max())
