/* The header of an FMU state's bytes (state_bytes.c writes them; the engine's loader and the pythonfmu kind's
 * loader shim check them): self-contained, so that the shim compiles it without the engine. */
#ifndef MBS_STATE_HEADER_H
#define MBS_STATE_HEADER_H
#include <stddef.h>
#include <stdint.h>

/* FMU state bytes: "MBSS", uint32 format version, char guid[64], uint64 payload length, uint64 FNV-1a-64 of the
 * payload, then the payload (state_bytes.c) */
#define MBS_STATE_VERSION 1u
#define MBS_STATE_HEADER (4 + 4 + 64 + 8 + 8)
uint64_t mbs_state_checksum(const unsigned char *payload, size_t n);
/* NULL if bytes[0..n) carry the header of a state of the model `guid` (magic, version, GUID, length, checksum)
 * with at least `min_payload` bytes of payload; else why not */
const char *mbs_state_header_problem(const void *bytes, size_t n, size_t min_payload, const char *guid);
#endif
