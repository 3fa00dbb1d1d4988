# CMake toolchain: zig's cc as the C compiler for a target given by ZIG_TARGET (default x86_64-linux-gnu.2.17: the
# project's own build, FMUs and stepper library, linked against glibc 2.17). zig comes from $ZIG, else from the
# ziglang package of Python3_EXECUTABLE (or python3): `python -m ziglang`. docs/portability.md.
# The project's CMake files place binaries for Linux x86_64 only (binaries/linux64, x86_64-linux): the other
# platforms come from fmus/cross/build_all_platforms.py.
#
#   cmake -S . -B build-glibc217 -DCMAKE_TOOLCHAIN_FILE=cmake/zig-cc.cmake -DPython3_EXECUTABLE=$PWD/.venv/bin/python
#   cmake --build build-glibc217 --target fmu_binaries
#
# CMake cannot take "python -m ziglang cc -target ..." as a compiler, so this file writes small wrapper scripts
# (cc, ar, ranlib) into the build folder. The project's native build (build/) is not touched.
set(ZIG_TARGET "x86_64-linux-gnu.2.17" CACHE STRING "zig cc -target of this build")
set(CMAKE_TRY_COMPILE_PLATFORM_VARIABLES ZIG_TARGET Python3_EXECUTABLE)

if(ZIG_TARGET MATCHES "windows")
  set(CMAKE_SYSTEM_NAME Windows)
elseif(ZIG_TARGET MATCHES "macos")
  set(CMAKE_SYSTEM_NAME Darwin)
else()
  set(CMAKE_SYSTEM_NAME Linux)
endif()
string(REGEX MATCH "^[^-]+" CMAKE_SYSTEM_PROCESSOR "${ZIG_TARGET}")

if(DEFINED ENV{ZIG})
  set(zig_command "\"$ENV{ZIG}\"")
else()
  if(Python3_EXECUTABLE)
    set(zig_python "${Python3_EXECUTABLE}")
  else()
    find_program(zig_python NAMES python3 python REQUIRED)
  endif()
  set(zig_command "\"${zig_python}\" -m ziglang")
endif()

set(zig_wrappers "${CMAKE_BINARY_DIR}/zig-wrappers")
file(MAKE_DIRECTORY "${zig_wrappers}")
foreach(tool cc ar ranlib)
  set(arguments "${tool}")
  if(tool STREQUAL cc)
    set(arguments "cc -target ${ZIG_TARGET}")
  endif()
  file(WRITE "${zig_wrappers}/${tool}" "#!/bin/sh\nexec ${zig_command} ${arguments} \"$@\"\n")
  file(CHMOD "${zig_wrappers}/${tool}" PERMISSIONS OWNER_READ OWNER_WRITE OWNER_EXECUTE GROUP_READ GROUP_EXECUTE
       WORLD_READ WORLD_EXECUTE)
endforeach()
set(CMAKE_C_COMPILER "${zig_wrappers}/cc")
# As fmus/cross/build_all_platforms.py: no FMA contraction (gcc's default under -std=c99).
set(CMAKE_C_FLAGS_INIT "-ffp-contract=off")
set(CMAKE_AR "${zig_wrappers}/ar" CACHE FILEPATH "zig ar")
set(CMAKE_RANLIB "${zig_wrappers}/ranlib" CACHE FILEPATH "zig ranlib")
