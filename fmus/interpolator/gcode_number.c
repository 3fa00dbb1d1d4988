/* Plain decimal numbers (see gcode_number.h); the same steps as models/interpolator/numbers.py. */
#include "gcode_number.h"

#include <stdio.h>

#include "model_constants.h"

static const double POW10[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
                                 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

NumberStatus gc_read_number(const char *s, size_t n, size_t *i, double *value) {
    int negative = 0, digits = 0, scale = 0, seen_point = 0, any_digit = 0;
    unsigned long long mantissa = 0;
    if (*i < n && (s[*i] == '+' || s[*i] == '-')) {
        negative = s[*i] == '-';
        (*i)++;
    }
    while (*i < n && ((s[*i] >= '0' && s[*i] <= '9') || (s[*i] == '.' && !seen_point))) {
        if (s[*i] == '.') {
            seen_point = 1;
        } else {
            int d = s[*i] - '0';
            any_digit = 1;
            if (mantissa == 0 && d == 0) {
                if (seen_point) scale++;
            } else {
                digits++;
                if (digits > MAX_SIGNIFICANT_DIGITS) return NUMBER_TOO_MANY_DIGITS;
                mantissa = mantissa * 10u + (unsigned)d;
                if (seen_point) scale++;
            }
        }
        (*i)++;
    }
    if (!any_digit) return NUMBER_MISSING;
    /* trailing zeros of the fraction: the same value, and 10^scale stays exact */
    while (scale > 0 && mantissa % 10u == 0 && mantissa != 0) {
        mantissa /= 10u;
        scale--;
    }
    if (mantissa == 0) scale = 0;
    if (scale > 22) return NUMBER_TOO_MANY_DECIMALS;
    *value = scale ? (double)mantissa / POW10[scale] : (double)mantissa;
    if (negative) *value = -*value;
    return NUMBER_OK;
}

void gc_number_expected(NumberStatus status, const char *what, char *expected, size_t size) {
    if (status == NUMBER_TOO_MANY_DIGITS)
        snprintf(expected, size, "at most %d significant digits in the number after %s", MAX_SIGNIFICANT_DIGITS, what);
    else if (status == NUMBER_TOO_MANY_DECIMALS)
        snprintf(expected, size, "at most 22 decimals in the number after %s", what);
    else
        snprintf(expected, size, "a number after %s", what);
}
