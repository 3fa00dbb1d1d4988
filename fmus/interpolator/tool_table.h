/* The tool table in LinuxCNC's format (the String parameter tool_table), as documented in
 * models/interpolator/tool_table.py (the Python reference of tool_table.c). */
#ifndef TOOL_TABLE_H
#define TOOL_TABLE_H

#include <stddef.h>

#include "gcode_parser.h"

/* Parses `length` bytes of `text`. Returns 0 with `*tools` (malloc'd, free() it; NULL when empty) and `*n_tools`,
 * or -1 with "<file> line <n>: \"<text>\": <what was expected>" in `error`. */
int tool_table_parse(const char *text, size_t length, const char *file, GcTool **tools, size_t *n_tools, char *error,
                     size_t error_size);

/* The tool numbered `number`, or NULL. */
const GcTool *tool_table_find(const GcTool *tools, size_t n_tools, int number);

#endif
