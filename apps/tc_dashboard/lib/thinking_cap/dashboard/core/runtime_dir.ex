defmodule ThinkingCap.Dashboard.Core.RuntimeDir do
  @moduledoc false
  # The dashboard's runtime files (yaws' logs): a directory of mode 0700 of
  # its own, under $XDG_RUNTIME_DIR when that is a private directory of
  # this user, else under the system's temporary directory, removed when
  # the dashboard stops. Nothing in it holds the token (access logging is
  # off), and no other user can read it anyway.

  @key {__MODULE__, :dir}

  @doc "The directory, made on first use."
  @spec path() :: Path.t()
  def path do
    case :persistent_term.get(@key, nil) do
      nil ->
        dir = Path.join(base(), "thinkingcap-#{System.pid()}-#{random()}")
        File.mkdir_p!(dir)
        File.chmod!(dir, 0o700)
        :persistent_term.put(@key, dir)
        dir

      dir ->
        dir
    end
  end

  @doc "Removes the directory (and what is in it), if it was made."
  @spec remove() :: :ok
  def remove do
    case :persistent_term.get(@key, nil) do
      nil ->
        :ok

      dir ->
        File.rm_rf(dir)
        :persistent_term.erase(@key)
        :ok
    end
  end

  defp base do
    case System.get_env("XDG_RUNTIME_DIR") do
      dir when is_binary(dir) and dir != "" ->
        if private?(dir), do: dir, else: System.tmp_dir!()

      _ ->
        System.tmp_dir!()
    end
  end

  defp private?(dir) do
    case File.stat(dir) do
      {:ok, %{type: :directory, mode: mode}} -> Bitwise.band(mode, 0o077) == 0
      _ -> false
    end
  end

  defp random, do: 6 |> :crypto.strong_rand_bytes() |> Base.url_encode64(padding: false)
end
