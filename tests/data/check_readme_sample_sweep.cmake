# cmake -DREADME=FILE -DCOMMAND_LINE="idm-model sweep ..." -P check_readme_sample_sweep.cmake
# Passes when README.md's gap quick-start writes the sample sweep the tests read: the command
# line (lines continued with a backslash joined, blanks collapsed) followed by --out.
file(READ "${README}" text)
string(REGEX REPLACE "\\\\\n[ ]*" " " text "${text}")
string(REGEX REPLACE "[ ]+" " " text "${text}")
string(FIND "${text}" "${COMMAND_LINE} --out " at)
if(at EQUAL -1)
  message(FATAL_ERROR
    "${README}: the gap quick-start does not write the sample sweep the tests read "
    "(tests/CMakeLists.txt, IDM_SAMPLE_SWEEP_ARGS); expected the line\n"
    "  ${COMMAND_LINE} --out DIR")
endif()
message(STATUS "${README}: the gap quick-start writes the tests' sample sweep")
