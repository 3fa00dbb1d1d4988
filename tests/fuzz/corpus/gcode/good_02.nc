(a)
; b

