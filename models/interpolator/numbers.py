"""The plain decimal numbers of part programs, Sinumerik expressions and tool tables, read one way everywhere.
Mirrors ``fmus/interpolator/gcode_number.c``."""
from __future__ import annotations

MAX_SIGNIFICANT_DIGITS = 17
MAX_DECIMALS = 22


class NumberError(ValueError):
    """Not a number where one was expected; ``expected`` says what was (``... after <what>``)."""

    def __init__(self, expected: str):
        self.expected = expected
        super().__init__(expected)


def read_number(text: str, i: int, what: str) -> tuple[float, int]:
    """The number ``[+-]digits[.digits]`` or ``[+-].digits`` at ``text[i:]`` (nothing skipped before it) and the
    index after it. At most MAX_SIGNIFICANT_DIGITS significant digits and 22 decimals; the value is
    mantissa / 10^decimals with trailing zeros of the fraction dropped, as the C code computes it."""
    n = len(text)
    negative = False
    if i < n and text[i] in "+-":
        negative = text[i] == "-"
        i += 1
    mantissa, digits, scale, seen_point, any_digit = 0, 0, 0, False, False
    while i < n and (text[i] in "0123456789" or (text[i] == "." and not seen_point)):
        if text[i] == ".":
            seen_point = True
        else:
            any_digit = True
            d = ord(text[i]) - 48
            if mantissa == 0 and d == 0:
                if seen_point:
                    scale += 1
            else:
                digits += 1
                if digits > MAX_SIGNIFICANT_DIGITS:
                    raise NumberError(f"at most {MAX_SIGNIFICANT_DIGITS} significant digits in the number after {what}")
                mantissa = mantissa * 10 + d
                if seen_point:
                    scale += 1
        i += 1
    if not any_digit:
        raise NumberError(f"a number after {what}")
    while scale > 0 and mantissa % 10 == 0 and mantissa != 0:
        mantissa //= 10
        scale -= 1
    if mantissa == 0:
        scale = 0
    if scale > MAX_DECIMALS:
        raise NumberError(f"at most {MAX_DECIMALS} decimals in the number after {what}")
    value = float(mantissa) / (10.0 ** scale) if scale else float(mantissa)
    return (-value if negative else value), i
