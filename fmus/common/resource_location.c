/* The resource location of FMI 2 (a file URI) and FMI 3 (a path) as a file path: resource_location.h. */
#include "resource_location.h"

#include <stdio.h>
#include <string.h>

static int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static int fail(char *message, size_t message_size, const char *location, const char *why) {
    if (message && message_size > 0)
        snprintf(message, message_size, "the resource location '%.200s' %s", location, why);
    return -1;
}

int fmu_resource_file(const char *location, const char *name, char *path, size_t size, char *message,
                      size_t message_size) {
    const char *s = location;
    size_t n = 0, name_length = strlen(name);
    const int uri = strncmp(s, "file:", 5) == 0;
    if (size == 0) return fail(message, message_size, location, "is too long");
    if (uri) {
        s += 5;
        if (strncmp(s, "//", 2) == 0) { /* file://host/path: only an empty host or localhost is local */
            s += 2;
            if (strncmp(s, "localhost/", 10) == 0)
                s += 9;
            else if (*s != '/')
                return fail(message, message_size, location, "is not a local file URI");
        }
#if defined(_WIN32)
        /* file:///C:/dir: the path is C:/dir, not /C:/dir */
        if (s[0] == '/' && ((s[1] >= 'A' && s[1] <= 'Z') || (s[1] >= 'a' && s[1] <= 'z')) && s[2] == ':') s++;
#endif
    }
    while (*s) {
        char c = *s;
        if (uri && c == '%') {
            if (hex_value(s[1]) < 0 || hex_value(s[2]) < 0 || (s[1] == '0' && s[2] == '0')) /* %00 cuts the path */
                return fail(message, message_size, location, "has a bad percent-escape");
            c = (char)(hex_value(s[1]) * 16 + hex_value(s[2]));
            s += 3;
        } else {
            s++;
        }
        if (n + 1 >= size) break;
        path[n++] = c;
    }
    if (*s || n + 1 + name_length + 1 > size) return fail(message, message_size, location, "is too long");
#if defined(_WIN32)
    if (n > 0 && path[n - 1] == '\\') n--; /* an FMI 3 resource path ending in a backslash */
#endif
    if (n == 0 || path[n - 1] != '/') path[n++] = '/';
    memcpy(path + n, name, name_length + 1);
    return 0;
}
