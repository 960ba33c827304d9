/* FMU state header (state_header.h). */
#include "state_header.h"

#include <string.h>

uint64_t mbs_state_checksum(const unsigned char *payload, size_t n) {
    uint64_t h = 1469598103934665603ull;  /* FNV-1a-64 */
    size_t i;
    for (i = 0; i < n; i++) h = (h ^ payload[i]) * 1099511628211ull;
    return h;
}

const char *mbs_state_header_problem(const void *bytes, size_t n, size_t min_payload, const char *guid) {
    const unsigned char *b = (const unsigned char *)bytes;
    uint32_t version;
    uint64_t length, sum;
    if (!b || n < MBS_STATE_HEADER + min_payload) return "not an mbsfmu FMU state (too short for its header)";
    if (memcmp(b, "MBSS", 4)) return "not an mbsfmu FMU state (bad magic)";
    memcpy(&version, b + 4, 4);
    memcpy(&length, b + 72, 8);
    memcpy(&sum, b + 80, 8);
    if (version != MBS_STATE_VERSION) return "the FMU state has another format version";
    if (!memchr(b + 8, 0, 64) || strcmp((const char *)b + 8, guid))
        return "the FMU state belongs to another model (GUID differs)";
    if (length != n - MBS_STATE_HEADER) return "the FMU state is truncated or has trailing bytes (length field disagrees)";
    if (mbs_state_checksum(b + MBS_STATE_HEADER, n - MBS_STATE_HEADER) != sum)
        return "FMU state checksum mismatch (corrupt bytes)";
    return NULL;
}
