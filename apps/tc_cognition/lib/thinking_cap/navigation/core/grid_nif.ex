defmodule ThinkingCap.Navigation.Core.GridNif do
  @moduledoc false
  # The grid NIF (c_src/tc_grid.c, tc_plan.c, tc_mcl.c): a fuzzy grid map
  # held as a resource, A* and D* Lite (a D* Lite search is a resource too),
  # a likelihood field and a particle set for localization, and pure
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

  def cost_map(_cells, _w, _h, _radius, _band, _peak, _old, _max),
    do: :erlang.nif_error(:nif_not_loaded)

  def diff(_a, _b, _max), do: :erlang.nif_error(:nif_not_loaded)
  def blocked(_occupancy, _threshold, _unknown), do: :erlang.nif_error(:nif_not_loaded)
  def overlay(_data, _mask, _value), do: :erlang.nif_error(:nif_not_loaded)
  def patch(_cells, _changes), do: :erlang.nif_error(:nif_not_loaded)

  def shrink(_occupancy, _w, _h, _k), do: :erlang.nif_error(:nif_not_loaded)

  def frontiers(_occupancy, _w, _h, _free_below, _min_size),
    do: :erlang.nif_error(:nif_not_loaded)

  def crisp(_occupancy, _w, _h), do: :erlang.nif_error(:nif_not_loaded)

  def rooms(_occupancy, _w, _h, _free_below, _half_door, _min_core),
    do: :erlang.nif_error(:nif_not_loaded)

  def field_new(_occupancy, _w, _h, _res, _ox, _oy, _threshold, _strict),
    do: :erlang.nif_error(:nif_not_loaded)

  def field_score(_field, _beams, _model, _pose), do: :erlang.nif_error(:nif_not_loaded)

  def field_through(_field, _beams, _model, _pose), do: :erlang.nif_error(:nif_not_loaded)

  def field_fit(_field, _beams, _model, _pose, _tolerance), do: :erlang.nif_error(:nif_not_loaded)

  def field_search(_field, _beams, _model, _step, _headings, _top, _box),
    do: :erlang.nif_error(:nif_not_loaded)

  def pf_new(_poses, _seed), do: :erlang.nif_error(:nif_not_loaded)
  def pf_spread(_pf, _pose, _sigmas), do: :erlang.nif_error(:nif_not_loaded)
  def pf_move(_pf, _delta, _alphas), do: :erlang.nif_error(:nif_not_loaded)
  def pf_weigh(_pf, _field, _beams, _model, _scale), do: :erlang.nif_error(:nif_not_loaded)
  def pf_resample(_pf, _share, _poses), do: :erlang.nif_error(:nif_not_loaded)
  def pf_estimate(_pf), do: :erlang.nif_error(:nif_not_loaded)
  def pf_mode(_pf, _radius), do: :erlang.nif_error(:nif_not_loaded)
  def pf_best(_pf), do: :erlang.nif_error(:nif_not_loaded)
  def pf_sample(_pf, _k), do: :erlang.nif_error(:nif_not_loaded)

  def fmap_replay(_map, _poses, _ranges, _beams, _meta, _ks, _fade, _lambdas, _margin),
    do: :erlang.nif_error(:nif_not_loaded)

  def pf_transform(_pf, _from, _to), do: :erlang.nif_error(:nif_not_loaded)

  def slam_match(_ref, _query, _guess, _window, _res, _sigma),
    do: :erlang.nif_error(:nif_not_loaded)

  def slam_optimize(_nodes, _edges, _iterations), do: :erlang.nif_error(:nif_not_loaded)
  def astar(_cells, _w, _h, _start, _goal), do: :erlang.nif_error(:nif_not_loaded)
  def astar_cpu(_cells, _w, _h, _start, _goal), do: :erlang.nif_error(:nif_not_loaded)
  def costs(_cells, _w, _h, _start, _targets), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_new(_cells, _w, _h, _start, _goal), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_update(_dsl, _changes), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_sync(_dsl, _cells, _max), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_sync(_dsl, _cells, _max, _hint), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_move_start(_dsl, _cell), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_plan(_dsl), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_forget_path(_dsl), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_cpu_ns(_dsl), do: :erlang.nif_error(:nif_not_loaded)
  def dsl_queued(_dsl), do: :erlang.nif_error(:nif_not_loaded)
end
