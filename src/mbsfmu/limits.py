"""Bounds on the work a scene file (or a command) may ask for (issue 12): every hostile input is refused early
and cheaply. The one source of these numbers: messages, `--help` and docs/ quote them from here.

Each limit is far above what a hand-written scene or a real elastic body needs.
"""

DOCUMENT_BYTES = 8 * 2**20      # a scene file; large nodal data belongs in an .npz beside it
DEPTH = 64                      # nesting of mappings and lists, aliases expanded (nodal arrays need 3-4)
NODES = 400_000                 # values in a document (a 10,000-body chain has 250,000): about 2 s to read
ENTRIES = 10_000                # items of one list or mapping (bodies, forces, outputs, parameters, inline rows)
NAME_CHARS = 200                # a model, body, parameter, input, output or coordinate name
ALIAS_NODES = 1_000_000         # nodes that aliases may add to the document once expanded
SCALAR_CHARS = 65_536           # one string (a description, an expression)
INT_CHARS = 100                 # one integer literal (digits, sign, base prefix)
EXPRESSION_CHARS = 4096         # one numeric expression
URDF_ELEMENTS_PER_LINK = 32     # XML elements a URDF may spend per link it may have (ENTRIES): a plain chain
                                # needs 11, Talos 20 (1,939 with visuals, collisions and transmissions)
URDF_ELEMENTS = ENTRIES * URDF_ELEMENTS_PER_LINK  # so a URDF of ENTRIES links is never refused by its elements
MESSAGE_CHARS = 400             # an error message (quoted input is shortened)

NPZ_BYTES = 64 * 2**20          # an .npz file, and the arrays read from it (declared uncompressed sizes)
MESH_BYTES = 64 * 2**20         # a mesh file (STL, OBJ, DAE) of a shape: checked at load, bounded again when read
MESH_TRIANGLES = 2_000_000      # triangles of one mesh (STL; OBJ and DAE polygons counted as their fans; DAE: per instance), counted as read
MESH_VERTICES = 2_000_000       # vertices of one OBJ mesh ('v' lines) or DAE mesh (per instance), counted as read
MESH_INSTANCES = 4096           # geometry instances of one DAE mesh (nested <instance_node>s multiply them), counted as bound
NPZ_ENTRIES = 64                # members of an .npz (zip) file
DRAWING_BYTES = 16 * 2**20      # an FMU's drawing description (the normalized scene as JSON, nodal data inline)
BEAM_ELEMENTS = 200             # the beam generator's dense FE matrices grow as elements²
FE_BYTES = 256 * 2**20          # one file of an FE model (matrix, nodes, .inp): a 50,000-DOF tet10 part needs ~60 MiB
FE_DOFS = 300_000               # degrees of freedom of an FE model (3 per node)
FE_ENTRIES = 16_000_000         # stored entries of one FE matrix (header and lines counted before they are read)
FE_MODES = 100                  # modes a reduction keeps (elastic coordinates of one body)
FE_STRESS_NODES = 256           # nodes of one FE body with von Mises outputs: 6 numbers per node and mode, in the
                                # compiled scene and (as JSON) in the drawing description
FE_AVERAGED_NODES = 1000        # nodes of an interface that keeps its deformation (RBE3): a dense (3n)² block
FE_MESH_BYTES = 64 * 2**20      # a solid mesh (elastic: fe: mesh:) read into memory whole before it is parsed
FE_PARSE_BYTES = 2 * 2**30      # address space of the child process that parses a solid mesh (meshio, numpy)
FE_PARSE_SECONDS = 30           # its CPU time

RTOL = (1e-14, 1.0)             # integrator.rtol: below 1e-14 no double-precision step can meet it
MAGNITUDE = (1e-100, 1e100)     # a nonzero constant (a mass, a length, a tolerance): its products stay finite and normal
AXIS_LENGTH = (1e-9, 1e100)     # joint and rotation axes: a direction needs a length that squares safely
COMMUNICATION_POINTS = 1e8      # (stop - start) / step of the experiment
RESULT_POINTS = 10_000_000      # communication points a run keeps in memory (`mbsfmu simulate`, a sweep case)
TABLE_ROWS = 21                 # rows the table of `mbsfmu simulate` shows at most (every n-th and the last)
DOMAIN_SAMPLES = 257            # times in [start, stop] at which drives and forces (and derivatives) are evaluated


def open_regular(path):
    """A binary file object of `path`, which must be a regular file: a FIFO, a device (/dev/zero) or a folder
    is refused before anything waits on it (opening a FIFO would block until a writer comes)."""
    import os
    import stat
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise IsADirectoryError(0, "not a regular file (a folder, FIFO or device)", str(path))
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
