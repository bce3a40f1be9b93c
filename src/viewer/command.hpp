// The csb-view command: a mesh file simulated as a cloth, live in a window or offscreen into
// frames (`csb-view --help` lists its options).
#pragma once

namespace csb::viewer {

// Runs the command on argv[0..argc) (argv[0] the program's name) and returns its exit status:
// 0, or 2 after printing to stderr why (bad options, a file that cannot be read, a method that
// cannot step the mesh).
int command(int argc, const char* const* argv);

}  // namespace csb::viewer
