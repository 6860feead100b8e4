defmodule ThinkingCap.Navigation.Core.GridNif do
  @moduledoc false
  # The grid NIF (c_src/tc_grid.c, tc_plan.c): a fuzzy grid map held as a
  # resource, A* and D* Lite (a D* Lite search is a resource too), and pure
  # functions on byte grids (distance transform, inflation, thresholds,
  # downsampling, patches, difference, room segmentation). Callers go through
  # ThinkingCap.Navigation.Maps.SensedGrid and ThinkingCap.Navigation.CostMap.

  @on_load :load_nif

  defp load_nif do
    path = :filename.join(:code.priv_dir(:tc_cognition), ~c"lib/tc_grid")
    :erlang.load_nif(path, 0)
  end

  def fmap_new(_w, _h, _res, _ox, _oy), do: :erlang.nif_error(:nif_not_loaded)

  def fmap_integrate(_map, _sx, _sy, _rays, _range_max, _fade, _lambda, _margin),
    do: :erlang.nif_error(:nif_not_loaded)

  def fmap_occupancy(_map, _c0, _r0, _w, _h, _known), do: :erlang.nif_error(:nif_not_loaded)
  def fmap_bbox(_map), do: :erlang.nif_error(:nif_not_loaded)
  def fmap_degrees(_map, _c, _r), do: :erlang.nif_error(:nif_not_loaded)
  def fmap_seed(_map, _occupancy, _strength), do: :erlang.nif_error(:nif_not_loaded)
  def fmap_export(_map), do: :erlang.nif_error(:nif_not_loaded)
  def fmap_import(_map, _binary), do: :erlang.nif_error(:nif_not_loaded)
  def edt(_cells, _w, _h), do: :erlang.nif_error(:nif_not_loaded)
  def inflate(_cells, _w, _h, _radius), do: :erlang.nif_error(:nif_not_loaded)
  def diff(_a, _b, _max), do: :erlang.nif_error(:nif_not_loaded)
  def blocked(_occupancy, _threshold, _unknown), do: :erlang.nif_error(:nif_not_loaded)
  def downsample(_cells, _w, _h, _k), do: :erlang.nif_error(:nif_not_loaded)
  def patch(_cells, _changes), do: :erlang.nif_error(:nif_not_loaded)

  def frontiers(_occupancy, _w, _h, _free_below, _min_size),
    do: :erlang.nif_error(:nif_not_loaded)

  def rooms(_occupancy, _w, _h, _free_below, _half_door, _min_core),
    do: :erlang.nif_error(:nif_not_loaded)

  def astar(_cells, _w, _h, _start, _goal), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_new(_cells, _w, _h, _start, _goal), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_update(_dsl, _changes), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_move_start(_dsl, _cell), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_plan(_dsl), do: :erlang.nif_error(:nif_not_loaded)
end
