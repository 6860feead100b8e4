/* tc_edt: the exact Euclidean distance transform shared by the grid NIF's
 * parts (see tc_edt.c). */
#ifndef TC_EDT_H
#define TC_EDT_H

/* squared distances (cells, centre to centre) from every cell of a w x h
 * grid to the nearest seed (a non-zero byte of `seeds`); INFINITY where
 * there is none. A malloc'd array (the caller frees it), or NULL. */
double *tc_edt2(const unsigned char *seeds, int w, int h);

/* the nearest seed of every cell (its index r * w + c; -1 where there is
 * none). A malloc'd array (the caller frees it), or NULL. */
int *tc_edt2_nearest(const unsigned char *seeds, int w, int h);

#endif
