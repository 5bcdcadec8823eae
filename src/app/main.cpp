#include "app/commands.h"
#include "core/distributed.h"

int main(int argc, char **argv) {
    meso::dist::init(&argc, &argv);  // MPI only when started by mpirun / srun (docs/cluster.md)
    const int rc = meso::run_cli(argc, argv);
    meso::dist::finalize();
    return rc;
}
