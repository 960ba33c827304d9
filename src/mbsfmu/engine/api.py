"""ctypes declarations of mbs_engine.h (the one seam between Python and the engine)."""

import ctypes

c_int, c_double, c_size_t, c_char_p, c_void_p = ctypes.c_int, ctypes.c_double, ctypes.c_size_t, ctypes.c_char_p, ctypes.c_void_p
P_double = ctypes.POINTER(ctypes.c_double)
LOGGER = ctypes.CFUNCTYPE(None, c_void_p, c_int, c_char_p)
STEP_OBSERVER = ctypes.CFUNCTYPE(None, c_void_p, c_double, P_double)

SIGNATURES = {
    "mbs_model_load": (c_void_p, [c_char_p, c_size_t, c_char_p, c_size_t]),
    "mbs_model_load_file": (c_void_p, [c_char_p, c_char_p, c_size_t]),
    "mbs_model_free": (None, [c_void_p]),
    "mbs_model_guid": (c_char_p, [c_void_p]),
    "mbs_model_nvars": (c_int, [c_void_p]),
    "mbs_model_var_kind": (c_int, [c_void_p, c_int]),
    "mbs_model_var_name": (c_char_p, [c_void_p, c_int]),
    "mbs_model_npos": (c_int, [c_void_p]),
    "mbs_model_nvel": (c_int, [c_void_p]),
    "mbs_instance_new": (c_void_p, [c_void_p, LOGGER, c_void_p]),
    "mbs_instance_free": (None, [c_void_p]),
    "mbs_reset": (c_int, [c_void_p]),
    "mbs_set_real": (c_int, [c_void_p, c_int, c_double]),
    "mbs_set_reals": (c_int, [c_void_p, c_void_p, c_size_t, c_void_p, c_void_p]),
    "mbs_get_real": (c_int, [c_void_p, c_int, P_double]),
    "mbs_set_string": (c_int, [c_void_p, c_int, c_char_p]),
    "mbs_get_string": (c_int, [c_void_p, c_int, ctypes.POINTER(c_char_p)]),
    "mbs_set_start": (c_int, [c_void_p, c_int, c_double]),
    "mbs_initialize": (c_int, [c_void_p, c_double]),
    "mbs_do_step": (c_int, [c_void_p, c_double, c_double]),
    "mbs_run": (c_int, [c_void_p, c_void_p, c_int, c_void_p]),
    "mbs_set_step_observer": (c_int, [c_void_p, STEP_OBSERVER, c_void_p]),
    "mbs_time": (c_double, [c_void_p]),
    "mbs_state": (P_double, [c_void_p]),
    "mbs_nominals": (P_double, [c_void_p]),
    "mbs_message": (c_char_p, [c_void_p]),
    "mbs_stats": (None, [c_void_p, ctypes.POINTER(ctypes.c_long), P_double]),
    "mbs_state_size": (c_size_t, [c_void_p]),
    "mbs_state_save": (c_int, [c_void_p, c_char_p, c_size_t]),
    "mbs_state_load": (c_int, [c_void_p, c_char_p, c_size_t]),
    "mbs_equations": (c_int, [c_void_p, c_double, c_void_p, c_void_p, c_void_p, c_void_p]),
    "mbs_rhs": (c_int, [c_void_p, c_double, c_void_p, c_void_p]),
    "mbs_output_point": (c_int, [c_void_p, c_int, c_void_p, c_double, c_void_p]),
    "mbs_von_mises": (c_int, [c_void_p, c_int, c_void_p, P_double]),
    "mbs_set_time": (c_int, [c_void_p, c_double]),
    "mbs_set_state": (c_int, [c_void_p, c_void_p, c_size_t]),
    "mbs_derivatives": (c_int, [c_void_p, c_void_p, c_size_t]),
    "mbs_directional_derivative": (c_int, [c_void_p, c_void_p, c_size_t, c_void_p, c_size_t, c_void_p, c_void_p]),
    "mbs_adjoint_derivative": (c_int, [c_void_p, c_void_p, c_size_t, c_void_p, c_size_t, c_void_p, c_void_p]),
}


def declare(lib):
    for name, (res, args) in SIGNATURES.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib
