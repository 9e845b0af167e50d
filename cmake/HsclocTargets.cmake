# hscloc_add_library(NAME SOURCES ... [PUBLIC deps...] [PRIVATE deps...])
# One library per folder, named hscloc_<folder>; headers are included as "folder/file.h".
function(hscloc_add_library name)
  cmake_parse_arguments(ARG "" "" "SOURCES;PUBLIC;PRIVATE" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(${name} PUBLIC ${ARG_PUBLIC} PRIVATE ${ARG_PRIVATE})
  set_target_properties(${name} PROPERTIES POSITION_INDEPENDENT_CODE ON)
endfunction()

# hscloc_add_test(NAME SOURCES ... LIBS ... [FIXTURES fixture...])
# A GoogleTest executable whose cases are listed individually in ctest. FIXTURES names ctest
# fixtures its cases need (tests/CMakeLists.txt); ctest sets them up first.
function(hscloc_add_test name)
  if(NOT HSCLOC_BUILD_TESTS)
    return()
  endif()
  cmake_parse_arguments(ARG "" "" "SOURCES;LIBS;FIXTURES" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} hscloc_test_support GTest::gmock GTest::gtest_main)
  # Test names carry the executable's name so `ctest -R model_feature_io_test` selects a target.
  # Data and tool locations are compiled into hscloc_test_support (see util/CMakeLists.txt).
  set(properties "")
  if(ARG_FIXTURES)
    set(properties PROPERTIES FIXTURES_REQUIRED "${ARG_FIXTURES}")
  endif()
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 TEST_PREFIX "${name}." ${properties})
endfunction()
