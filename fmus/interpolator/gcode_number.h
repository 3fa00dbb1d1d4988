/* The plain decimal numbers of part programs, Sinumerik expressions and tool tables, read one way everywhere
 * (models/interpolator/numbers.py is the Python reference). */
#ifndef GCODE_NUMBER_H
#define GCODE_NUMBER_H

#include <stddef.h>

typedef enum { NUMBER_OK = 0, NUMBER_MISSING, NUMBER_TOO_MANY_DIGITS, NUMBER_TOO_MANY_DECIMALS } NumberStatus;

/* The number [+-]digits[.digits] or [+-].digits at s[*i] (nothing skipped before it); *i moves past what was
 * read, also on an error. At most MAX_SIGNIFICANT_DIGITS significant digits and 22 decimals; the value is
 * mantissa / 10^decimals with trailing zeros of the fraction dropped, as the reference computes it. */
NumberStatus gc_read_number(const char *s, size_t n, size_t *i, double *value);

/* What was expected, for a status other than NUMBER_OK: "a number after <what>", "at most 17 significant digits
 * in the number after <what>", "at most 22 decimals in the number after <what>". */
void gc_number_expected(NumberStatus status, const char *what, char *expected, size_t size);

#endif
