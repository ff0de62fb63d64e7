# Helper functions for somalab targets (in the spirit of COLMAP's
# cmake/CMakeHelper.cmake).

# soma_add_library(NAME core SRCS a.cc b.cc PUBLIC_LINK_LIBS x PRIVATE_LINK_LIBS y)
# Creates the static library target soma_<NAME> with alias soma::<NAME>.
function(soma_add_library)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;PUBLIC_LINK_LIBS;PRIVATE_LINK_LIBS" ${ARGN})
  set(target soma_${ARG_NAME})
  if(NOT ARG_SRCS)
    # A module whose first sources have not landed yet: header-only for now.
    add_library(${target} INTERFACE)
    add_library(soma::${ARG_NAME} ALIAS ${target})
    target_include_directories(${target} INTERFACE
      $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}> $<INSTALL_INTERFACE:${SOMA_INSTALL_INCLUDEDIR}>)
    set_target_properties(${target} PROPERTIES EXPORT_NAME ${ARG_NAME})
    set_property(GLOBAL APPEND PROPERTY SOMA_LIBRARIES ${target})
    target_link_libraries(${target} INTERFACE ${ARG_PUBLIC_LINK_LIBS})
    return()
  endif()
  add_library(${target} STATIC ${ARG_SRCS})
  add_library(soma::${ARG_NAME} ALIAS ${target})
  target_include_directories(${target} PUBLIC
    $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}> $<INSTALL_INTERFACE:${SOMA_INSTALL_INCLUDEDIR}>)
  # Installed and exported as soma::<NAME> (somalabConfig.cmake).
  set_target_properties(${target} PROPERTIES EXPORT_NAME ${ARG_NAME})
  target_link_libraries(${target} PUBLIC ${ARG_PUBLIC_LINK_LIBS} PRIVATE ${ARG_PRIVATE_LINK_LIBS})
  target_compile_options(${target} PRIVATE ${SOMA_WARNING_FLAGS})
  set_property(GLOBAL APPEND PROPERTY SOMA_LIBRARIES ${target})
endfunction()

# soma_add_test_executable(NAME config_tests SRCS a_test.cc LINK_LIBS soma::config)
# Tests are linked into one executable per module (fewer processes: each
# torch-linked process pays ~0.5 s to start); see tests/CMakeLists.txt.
function(soma_add_test_executable)
  cmake_parse_arguments(ARG "" "NAME" "SRCS;LINK_LIBS" ${ARGN})
  if(NOT ARG_SRCS)
    message(STATUS "somalab: no test sources for ${ARG_NAME} yet")
    return()
  endif()
  add_executable(${ARG_NAME} ${ARG_SRCS})
  target_link_libraries(${ARG_NAME} PRIVATE ${ARG_LINK_LIBS} soma_testing GTest::gmock)
  target_compile_options(${ARG_NAME} PRIVATE ${SOMA_WARNING_FLAGS})
  gtest_discover_tests(${ARG_NAME}
    WORKING_DIRECTORY ${PROJECT_SOURCE_DIR}
    DISCOVERY_TIMEOUT 60
    PROPERTIES ENVIRONMENT "SOMA_SOURCE_DIR=${PROJECT_SOURCE_DIR}")
endfunction()
