cmake_minimum_required(VERSION 3.20)
# The control for layering.cmake: runs it on a tree that breaks every rule and passes
# only when it exits non-zero AND names every expected violation. (ctest's
# PASS_REGULAR_EXPRESSION alone would ignore the exit code: a check that only warned
# would still pass.) Lines in REJECT (allowed includes) must not be named.
#   cmake -DCHECK=<layering.cmake> -DROOT=<bad tree> "-DEXPECT=line|line" ["-DREJECT=text|text"]
#         -P expect_failure.cmake
foreach(v CHECK ROOT EXPECT)
  if(NOT ${v})
    message(FATAL_ERROR "pass -D${v}=...")
  endif()
endforeach()
string(REPLACE "|" ";" EXPECT "${EXPECT}")
string(REPLACE "|" ";" REJECT "${REJECT}")
execute_process(COMMAND ${CMAKE_COMMAND} -DROOT=${ROOT} -P ${CHECK}
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
set(all "${out}${err}")
if(rc EQUAL 0)
  message(FATAL_ERROR "the check passed a tree that breaks the layering (exit 0):\n${all}")
endif()
set(missing "")
foreach(e IN LISTS EXPECT)
  string(FIND "${all}" "${e}" at)
  if(at EQUAL -1)
    string(APPEND missing "\n  ${e}")
  endif()
endforeach()
if(missing)
  message(FATAL_ERROR "the check failed (exit ${rc}) but did not name:${missing}\noutput:\n${all}")
endif()
foreach(r IN LISTS REJECT)
  string(FIND "${all}" "${r}" at)
  if(NOT at EQUAL -1)
    message(FATAL_ERROR "the check named an allowed include (${r}):\n${all}")
  endif()
endforeach()
list(LENGTH EXPECT n)
message(STATUS "the check failed (exit ${rc}) and named all ${n} violations")
