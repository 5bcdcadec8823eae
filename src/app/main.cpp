#include "app/commands.h"

int main(int argc, char **argv) { return meso::run_cli(argc, argv); }
