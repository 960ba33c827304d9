/* Files an FMU reads at run time, for both FMU kinds (native: fmi2.c; pythonfmu: the loader shim fmu/shim.c
 * and, through mbs_model_load_file, the slave): fmuResourceLocation → a local path, and bounded reads of
 * regular files only (a FIFO, device or folder in place of a file would hang or exhaust the host). */
#ifndef MBS_FMU_FILES_H
#define MBS_FMU_FILES_H

#include <stddef.h>

#define MBS_SCENE_FILE_LIMIT ((size_t)1 << 30) /* a compiled scene: its instance workspace is bounded the same */

/* The file `file` in the folder named by the FMI 2.0 fmuResourceLocation `uri` (RFC 3986 "file" URI with an
 * absolute path: file:///dir, file:/dir, file://localhost/dir; percent escapes; trailing slash or not) into
 * out[n]. 0, or 1 with the reason in err. */
int mbs_resource_path(const char *uri, const char *file, char *out, size_t n, char *err, size_t errlen);

/* 0 if path names a regular file of at most limit bytes (its size in *size if size is not NULL), else 1 with
 * the reason in err. Opens without blocking (a FIFO never hangs). */
int mbs_check_regular(const char *path, size_t limit, size_t *size, char *err, size_t errlen);

/* The contents of the regular file path (at most limit bytes) in a malloc'ed buffer, its length in *len;
 * NULL with the reason in err. */
void *mbs_read_regular(const char *path, size_t limit, size_t *len, char *err, size_t errlen);

#endif
