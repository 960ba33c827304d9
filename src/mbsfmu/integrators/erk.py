"""Stage loop shared by the explicit embedded Runge–Kutta pairs (DOPRI5, DOP853)."""


def erk_stages(f, t, x, h, A, C, K, s):
    """Fill K[1:s] with k_i = f(t + c_i h, x + h Σ_j a_ij k_j); K[0] must already hold f(t, x)."""
    hA = h * A  # one scaling of the tableau instead of one per stage
    for i in range(1, s):
        # (row of h·A) @ K[:i] is a single BLAS call regardless of the number of stages
        K[i] = f(t + C[i] * h, x + hA[i, :i] @ K[:i])
    return hA
