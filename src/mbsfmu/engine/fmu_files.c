/* Files an FMU reads at run time (fmu_files.h): fmuResourceLocation → path; bounded regular-file reads. */
#if !defined(_WIN32) && !defined(_POSIX_C_SOURCE)
#define _POSIX_C_SOURCE 200809L
#endif
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <fcntl.h>
#ifdef _WIN32
#include <io.h>
#define open_file(path) _open(path, _O_RDONLY | _O_BINARY)
#define close_file _close
#define read_file(fd, buf, n) _read(fd, buf, (unsigned)(n))
typedef struct _stati64 file_stat;
#define stat_file _fstati64
#define IS_REGULAR(mode) (((mode) & _S_IFMT) == _S_IFREG)
#else
#include <unistd.h>
#ifndef O_CLOEXEC
#define O_CLOEXEC 0
#endif
/* O_NONBLOCK: opening a FIFO does not wait for a writer (and regular files ignore the flag) */
#define open_file(path) open(path, O_RDONLY | O_NONBLOCK | O_NOCTTY | O_CLOEXEC)
#define close_file close
#define read_file(fd, buf, n) read(fd, buf, n)
typedef struct stat file_stat;
#define stat_file fstat
#define IS_REGULAR(mode) S_ISREG(mode)
#endif

#include "fmu_files.h"

static int hexval(int ch) {
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

/* 1 if s starts with the lower-case ASCII word w in any case (URI schemes and host names, RFC 3986 3.1, 3.2.2) */
static int starts_nocase(const char *s, const char *w) {
    for (; *w; s++, w++)
        if (*s != *w && !(*w >= 'a' && *w <= 'z' && *s == *w - 'a' + 'A')) return 0;
    return 1;
}

/* After "file:": the absolute path, past an empty or "localhost" authority (RFC 8089: file:///p, file:/p,
 * file://localhost/p); NULL if there is another host or no absolute path. */
static const char *uri_path(const char *p) {
    if (strncmp(p, "//", 2) == 0) {
        p += 2;
        if (starts_nocase(p, "localhost") && p[9] == '/') p += 9;
    }
    if (*p != '/') return NULL;
#ifdef _WIN32
    if (p[1] && p[2] == ':') p++; /* /C:/dir → C:/dir */
#endif
    return p;
}

int mbs_resource_path(const char *uri, const char *file, char *out, size_t n, char *err, size_t errlen) {
    const char *p;
    size_t k = 0;
    if (!uri || !*uri) {
        snprintf(err, errlen, "no fmuResourceLocation given");
        return 1;
    }
    if (!starts_nocase(uri, "file:")) {
        snprintf(err, errlen, "fmuResourceLocation '%.300s' is not a file URI; FMI 2.0 passes the resources folder "
                 "as file:///absolute/path/resources (RFC 3986)", uri);
        return 1;
    }
    if (!(p = uri_path(uri + 5))) {
        snprintf(err, errlen, "fmuResourceLocation '%.300s': need a local absolute path (file:///dir, file:/dir or "
                 "file://localhost/dir)", uri);
        return 1;
    }
    for (; *p; p++) {
        int ch = (unsigned char)*p;
        if (ch == '?' || ch == '#') {
            snprintf(err, errlen, "fmuResourceLocation '%.300s': a query or fragment ('%c') names no folder; a '%c' "
                     "in a folder name is written %%%02X", uri, ch, ch, ch);
            return 1;
        }
        if (ch == '%') {
            int hi = hexval(p[1]), lo = hi < 0 ? -1 : hexval(p[2]);
            ch = hi * 16 + lo;
            if (lo < 0 || ch == 0 || ch == '/') {
                snprintf(err, errlen, "fmuResourceLocation '%.300s': bad percent escape '%.3s' (need %%XX, two hex "
                         "digits, not %%00 or %%2F)", uri, p);
                return 1;
            }
            p += 2;
        }
        if (k + 1 >= n) goto too_long;
        out[k++] = (char)ch;
    }
    if (out[k - 1] != '/') {
        if (k + 1 >= n) goto too_long;
        out[k++] = '/';
    }
    if (k + strlen(file) + 1 > n) goto too_long;
    strcpy(out + k, file);
    return 0;
too_long:
    snprintf(err, errlen, "fmuResourceLocation '%.300s': path too long (limit %zu bytes)", uri, n - 1);
    return 1;
}

/* An open descriptor of the regular file path with its size, or -1 with the reason in err. */
static int open_regular(const char *path, size_t limit, size_t *size, char *err, size_t errlen) {
    file_stat st;
    int fd = open_file(path);
    if (fd < 0) {
        snprintf(err, errlen, "cannot open '%.600s'", path);
        return -1;
    }
    if (stat_file(fd, &st) != 0 || !IS_REGULAR(st.st_mode)) {
        snprintf(err, errlen, "'%.600s' is not a regular file (a folder, FIFO, socket or device)", path);
    } else if ((unsigned long long)st.st_size > (unsigned long long)limit) {
        snprintf(err, errlen, "'%.600s' has %lld bytes, more than this FMU reads (limit %zu)", path,
                 (long long)st.st_size, limit);
    } else {
        *size = (size_t)st.st_size;
        return fd;
    }
    close_file(fd);
    return -1;
}

int mbs_check_regular(const char *path, size_t limit, size_t *size, char *err, size_t errlen) {
    size_t n;
    int fd = open_regular(path, limit, &n, err, errlen);
    if (fd < 0) return 1;
    close_file(fd);
    if (size) *size = n;
    return 0;
}

void *mbs_read_regular(const char *path, size_t limit, size_t *len, char *err, size_t errlen) {
    size_t n = 0, got = 0;
    char extra;
    int fd = open_regular(path, limit, &n, err, errlen);
    char *buf = fd < 0 ? NULL : (char *)malloc(n ? n : 1);
    if (fd < 0) return NULL;
    if (!buf) {
        snprintf(err, errlen, "out of memory reading '%.600s' (%zu bytes)", path, n);
        close_file(fd);
        return NULL;
    }
    while (got < n) {
        long r = (long)read_file(fd, buf + got, n - got);
        if (r <= 0) break;
        got += (size_t)r;
    }
    if (got != n || read_file(fd, &extra, 1) != 0) { /* shorter or longer than its size: changed under us */
        snprintf(err, errlen, "'%.600s' changed size while being read", path);
        free(buf);
        buf = NULL;
    }
    close_file(fd);
    *len = n;
    return buf;
}
