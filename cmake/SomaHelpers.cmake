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
  if(SOMA_ASAN)
    # An instrumented archive needs the sanitizer runtimes wherever it is
    # linked; add_link_options covers this tree only, the exported target
    # carries it to a find_package(somalab) consumer of an ASan install.
    target_link_options(${target} INTERFACE -fsanitize=address,undefined)
  endif()
  set_property(GLOBAL APPEND PROPERTY SOMA_LIBRARIES ${target})
endfunction()

# soma_add_test_executable(NAME config_tests MODULE config SRCS a_test.cc)
# soma_add_test_executable(NAME integration_tests FRAMEWORK SRCS a_test.cc)
# Tests are linked into one executable per module (fewer processes: each
# torch-linked process pays ~0.5 s to start); see tests/CMakeLists.txt.
# A MODULE executable links soma::<MODULE>, the core-only soma_testing
# helpers and the plain gtest main (soma_testing_main), plus LINK_LIBS (e.g.
# soma_testing_body); soma_check_test_layers() fails the configure step if
# any of it reaches above <MODULE>. A FRAMEWORK executable links the whole
# framework and the gtest main that calls InitFramework().
function(soma_add_test_executable)
  cmake_parse_arguments(ARG "FRAMEWORK" "NAME;MODULE" "SRCS;LINK_LIBS" ${ARGN})
  if(NOT ARG_SRCS)
    message(STATUS "somalab: no test sources for ${ARG_NAME} yet")
    return()
  endif()
  add_executable(${ARG_NAME} ${ARG_SRCS})
  if(ARG_FRAMEWORK)
    target_link_libraries(${ARG_NAME} PRIVATE soma::framework ${ARG_LINK_LIBS}
                          soma_testing soma_testing_framework_main GTest::gmock)
  elseif(ARG_MODULE)
    target_link_libraries(${ARG_NAME} PRIVATE soma::${ARG_MODULE} ${ARG_LINK_LIBS}
                          soma_testing soma_testing_main GTest::gmock)
    set_property(TARGET ${ARG_NAME} PROPERTY SOMA_TEST_MODULE ${ARG_MODULE})
    set_property(GLOBAL APPEND PROPERTY SOMA_MODULE_TEST_EXECUTABLES ${ARG_NAME})
  else()
    message(FATAL_ERROR "soma_add_test_executable(${ARG_NAME}): MODULE <module> or FRAMEWORK")
  endif()
  target_compile_options(${ARG_NAME} PRIVATE ${SOMA_WARNING_FLAGS})
  gtest_discover_tests(${ARG_NAME}
    WORKING_DIRECTORY ${PROJECT_SOURCE_DIR}
    DISCOVERY_TIMEOUT 60
    PROPERTIES ENVIRONMENT "SOMA_SOURCE_DIR=${PROJECT_SOURCE_DIR}")
endfunction()

# soma_link_closure(<out-var> <item>...): every library <item>s link,
# transitively (targets through LINK_LIBRARIES/INTERFACE_LINK_LIBRARIES,
# aliases resolved, $<LINK_ONLY:x> read as x), the items included.
function(soma_link_closure out)
  set(closure)
  set(queue ${ARGN})
  while(queue)
    list(POP_FRONT queue item)
    if(item MATCHES "^\\$<LINK_ONLY:(.*)>$")
      set(item "${CMAKE_MATCH_1}")
    endif()
    if(item MATCHES "^::@" OR item MATCHES "\\$<")
      continue()  # directory markers; other generator expressions
    endif()
    if(TARGET ${item})
      get_target_property(aliased ${item} ALIASED_TARGET)
      if(aliased)
        set(item ${aliased})
      endif()
    endif()
    if(item IN_LIST closure)
      continue()
    endif()
    list(APPEND closure ${item})
    if(TARGET ${item})
      get_target_property(type ${item} TYPE)
      set(links)
      if(NOT type STREQUAL "INTERFACE_LIBRARY")
        get_target_property(direct ${item} LINK_LIBRARIES)
        if(direct)
          list(APPEND links ${direct})
        endif()
      endif()
      get_target_property(interface ${item} INTERFACE_LINK_LIBRARIES)
      if(interface)
        list(APPEND links ${interface})
      endif()
      list(APPEND queue ${links})
    endif()
  endwhile()
  set(${out} ${closure} PARENT_SCOPE)
endfunction()

# soma_check_test_layers(): every MODULE test executable links only what its
# module's library links (the module and the modules below it, with their
# third-party libraries), the core-only test helpers and the plain gtest main,
# and soma_testing_body only where the module is at or above body. Every
# module benchmark (tests/bench/CMakeLists.txt) links only what its module's
# library links, the lower modules named in its SOMA_TEST_LOWER property
# (each defined before the module: below it in the layer order) and Google
# Benchmark. Anything else (a module above, soma::framework, torch or Ceres
# below model/solve, the framework-initialising main) fails the configure
# step. The CTest entry layers.test_executables checks the same on the graph
# of `cmake --graphviz` (cmake/check_test_layers.py).
function(soma_check_test_layers)
  get_property(tests GLOBAL PROPERTY SOMA_MODULE_TEST_EXECUTABLES)
  get_property(benchmarks GLOBAL PROPERTY SOMA_MODULE_BENCHMARKS)
  get_property(libraries GLOBAL PROPERTY SOMA_LIBRARIES)
  set(errors)
  foreach(test IN LISTS tests benchmarks)
    get_target_property(module ${test} SOMA_TEST_MODULE)
    if(test IN_LIST benchmarks)
      get_target_property(lower ${test} SOMA_TEST_LOWER)
      if(NOT lower)
        set(lower)
      endif()
      list(FIND libraries soma_${module} position)
      foreach(lib IN LISTS lower)
        list(FIND libraries ${lib} lib_position)
        if(lib_position LESS 0 OR lib_position GREATER position)
          list(APPEND errors "${test} (module ${module}) names ${lib}, which is not a module below ${module}")
        endif()
      endforeach()
      soma_link_closure(allowed soma_${module} ${lower} benchmark::benchmark
                        benchmark::benchmark_main)
    else()
      soma_link_closure(allowed soma_${module} soma_testing soma_testing_main GTest::gmock)
      if(soma_body IN_LIST allowed)
        list(APPEND allowed soma_testing_body)
      endif()
    endif()
    get_target_property(direct ${test} LINK_LIBRARIES)
    soma_link_closure(linked ${direct})
    foreach(item IN LISTS linked)
      if(NOT item IN_LIST allowed)
        list(APPEND errors "${test} (module ${module}) links ${item}, which soma_${module} does not")
      endif()
    endforeach()
  endforeach()
  if(errors)
    list(JOIN errors "\n  " text)
    message(FATAL_ERROR "somalab: test executables reach above their module "
                        "(tests/CMakeLists.txt, tests/bench/CMakeLists.txt):\n  ${text}")
  endif()
  list(LENGTH tests count)
  list(LENGTH benchmarks bench_count)
  message(STATUS "somalab: ${count} module test executables and ${bench_count} module "
                 "benchmarks link only their module and below")
endfunction()
