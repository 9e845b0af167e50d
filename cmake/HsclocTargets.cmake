# hscloc_add_library(NAME SOURCES ... [PUBLIC deps...] [PRIVATE deps...])
# One library per folder, named hscloc_<folder>; headers are included as "folder/file.h".
function(hscloc_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;PUBLIC;PRIVATE" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${ARG_PUBLIC} PRIVATE ${ARG_PRIVATE})
  set_target_properties(${name} PROPERTIES POSITION_INDEPENDENT_CODE ON)
endfunction()

# hscloc_add_test(NAME SOURCES ... LIBS ... [LABELS ...])
# A GoogleTest executable whose cases are listed individually in ctest.
function(hscloc_add_test name)
  if(NOT HSCLOC_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} hscloc_test_support GTest::gmock GTest::gtest_main)
  gtest_discover_tests(${name}
    DISCOVERY_TIMEOUT 60
    PROPERTIES LABELS "${ARG_LABELS}"
    ENVIRONMENT "HSCLOC_DATA_DIR=${HSCLOC_DATA_DIR};HSCLOC_COLMAP=${COLMAP_EXECUTABLE};QT_QPA_PLATFORM=offscreen")
endfunction()
