/* Runs the model's step on inputs from a test flight and prints every output. Each step sits
   between two marker calls, where the instruction-counting plugin reads its counter. */
#include <stdio.h>

#include "nsi_inputs.h"
#include "nsi_model.h"

__attribute__((noinline)) void nsi_mark_begin(void) { __asm volatile(""); }
__attribute__((noinline)) void nsi_mark_end(void) { __asm volatile(""); }

static float state[NSI_NSTATE];

int main(void)
{
    float out[NSI_NY];
    nsi_init(nsi_y_in[0], state);
    for (int k = 0; k < NSI_K; ++k) {
        nsi_mark_begin();
        nsi_step(nsi_y_in[k], nsi_u_in[k], state, out);
        nsi_mark_end();
        for (int i = 0; i < NSI_NY; ++i)
            printf("%.9g\n", (double)out[i]);
    }
    printf("done %d\n", NSI_K);
    return 0;
}
