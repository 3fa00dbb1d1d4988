/* The FMU's resources folder from the resource location the importer passed to instantiate, for every
 * model that reads a file of its resources/ (ForceNet's weights, the Interpolator's part program). */
#ifndef RESOURCE_LOCATION_H
#define RESOURCE_LOCATION_H

#include <stddef.h>

/* The path of the file `name` in the resources folder at `location`, as the importer passed it:
 * - FMI 2, a file URI: "file:///dir/resources/", "file:/dir/resources", "file://localhost/dir/resources",
 *   percent-escapes decoded (either case of hex digits); another host is not local and is rejected;
 * - FMI 3, a native path: anything not starting with "file:", taken as it is (a "%41" in a path stays).
 * A trailing '/' is optional. Writes at most `size` bytes to `path`. Returns 0, or -1 with the reason in
 * `message` ("is not a local file URI", "has a bad percent-escape", "is too long"). */
int fmu_resource_file(const char *location, const char *name, char *path, size_t size, char *message,
                      size_t message_size);

#endif
