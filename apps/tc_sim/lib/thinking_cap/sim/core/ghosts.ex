defmodule ThinkingCap.Sim.Core.Ghosts do
  @moduledoc false
  # The bodies each region of a simulation spread over nodes must hold in
  # its ray caster: its own robots, and the ghosts, every other body
  # (robots of other regions, walkers) within `reach` of the box around
  # its own robots. `reach` is the longest a sensor sees from a robot's
  # centre, plus the space a move and the contact test look at: a body
  # farther away cannot change a reading or a move of the region, so the
  # region computes exactly what a one-node simulation does.
  #
  # Regions are strips of the world along x, one per node, between
  # `borders` (ascending): a robot belongs to the strip its x is in.

  alias ThinkingCap.Sim.Raycast

  @record 32

  @doc """
  `%{region => bodies}` (records of `Raycast.body_record/4`, one binary
  each) for `own`, `%{region => [binary of records]}`, and the walkers'
  records `walkers` (a binary).
  """
  @spec bodies(%{term() => [binary()]}, binary(), float()) :: %{term() => binary()}
  def bodies(own, walkers, reach) do
    Map.new(own, fn {region, bins} ->
      case box(bins, reach) do
        nil ->
          {region, <<>>}

        box ->
          others = for {other, obins} <- own, other != region, bin <- obins, do: bin
          ghosts = for bin <- [walkers | others], do: within(bin, box)
          {region, IO.iodata_to_binary([bins | ghosts])}
      end
    end)
  end

  @doc "How many records a binary of body records holds."
  @spec count(binary()) :: non_neg_integer()
  def count(bin), do: div(byte_size(bin), @record)

  @doc "The index (0-based) of the strip that holds `x`, given the ascending borders."
  @spec strip([float()], float()) :: non_neg_integer()
  def strip(borders, x), do: Enum.count(borders, &(x >= &1))

  @doc """
  `n - 1` borders cutting the x-range `{x0, x1}` into `n` strips of equal
  width.
  """
  @spec even_borders({float(), float()}, pos_integer()) :: [float()]
  def even_borders({x0, x1}, n), do: for(k <- 1..(n - 1)//1, do: x0 + (x1 - x0) * k / n)

  # the box around the records' centres, grown by reach; nil if none
  defp box(bins, reach) do
    bins
    |> Enum.map(&Raycast.records_box/1)
    |> Enum.reject(&is_nil/1)
    |> case do
      [] ->
        nil

      boxes ->
        {ax, ay, bx, by} =
          Enum.reduce(boxes, fn {ax, ay, bx, by}, {cx, cy, dx, dy} ->
            {min(ax, cx), min(ay, cy), max(bx, dx), max(by, dy)}
          end)

        {ax - reach, ay - reach, bx + reach, by + reach}
    end
  end

  # the records of bin whose disc reaches into the box
  defp within(bin, {ax, ay, bx, by}), do: Raycast.records_within(bin, ax, ay, bx, by)
end
